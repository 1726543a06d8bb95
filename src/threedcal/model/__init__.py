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
# The frames DepthEstimator.points gives points in (threedcal.model.points), and the depth above
# which a pixel is in contact: above the most (25-35 µm) that the bench's calibrated DIGIT model
# reads outside the contact of a 1 mm press, so that its halo stays out (docs/how-to/deploy.md).
POINT_FRAMES = ("sensor", "printer")
CONTACT_DEPTH_MM = 0.05
# `threedcal live` warns when the no-contact region has drifted this far from the blank, in grey
# levels beyond a uniform shift (threedcal.model.drift.background_drift_dn): above the bench's
# floor (0.12 without contact, 0.27 beside a press), below what LEDs 5 % brighter give (0.6-0.8),
# which double the contact a bench model reads (docs/how-to/deploy.md, "Live").
BACKGROUND_DRIFT_WARN_DN = 0.5

__all__ = [
    "PRESET_NAMES",
    "DEFAULT_PRESET",
    "POINT_FRAMES",
    "CONTACT_DEPTH_MM",
    "BACKGROUND_DRIFT_WARN_DN",
]
