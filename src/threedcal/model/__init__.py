"""Image → surface-gradient models: presets, training, checkpoints and the inference API.

Heavy imports (torch) happen inside the submodules; `threedcal.model` itself stays light.
"""

from __future__ import annotations

PRESET_NAMES = (
    "touchnet",
    "compact",
    "compact_tiny",
    "context",
    "context_half",
    "multiscale",
    "lookup",
)
DEFAULT_PRESET = "compact"

__all__ = ["PRESET_NAMES", "DEFAULT_PRESET"]
