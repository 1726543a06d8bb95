"""Image → surface-gradient models: presets, training, checkpoints and the inference API.

Heavy imports (torch) happen inside the submodules; `threedcal.model` itself stays light.
"""

from __future__ import annotations

PRESET_NAMES = ("touchnet", "compact", "compact_tiny", "context", "multiscale", "lookup")
DEFAULT_PRESET = "compact"
# The frames DepthEstimator.points gives points in (threedcal.model.points), and the depth above
# which a pixel is in contact: five times the background depth a calibrated DIGIT model reads where
# nothing touches (docs/points.md).
POINT_FRAMES = ("sensor", "printer")
CONTACT_DEPTH_MM = 0.02
# `threedcal live` warns when the no-contact region has drifted this far from the blank, in grey
# levels (threedcal.model.drift.background_drift_dn; docs/models.md, "Live").
BACKGROUND_DRIFT_WARN_DN = 0.5

__all__ = [
    "PRESET_NAMES",
    "DEFAULT_PRESET",
    "POINT_FRAMES",
    "CONTACT_DEPTH_MM",
    "BACKGROUND_DRIFT_WARN_DN",
]
