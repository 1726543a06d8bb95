"""threedcal: calibrate vision-based tactile sensors with a 3D printer (the 3D Cal study as a workflow)."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("threedcal")
except PackageNotFoundError:  # running from a source tree without an install
    __version__ = "0.0.0+unknown"

__all__ = ["__version__"]
