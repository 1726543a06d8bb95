"""threedcal: calibrate vision-based tactile sensors with a 3D printer (the 3D Cal study as a workflow)."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("threedcal")
except PackageNotFoundError:  # running from a source tree without an install
    __version__ = "0.0.0+unknown"

__all__ = ["__version__", "DepthEstimator"]


def __getattr__(name: str):
    # Lazy: `import threedcal` stays light; torch loads on first use of the estimator.
    if name == "DepthEstimator":
        from threedcal.model.inference import DepthEstimator

        return DepthEstimator
    raise AttributeError(f"module 'threedcal' has no attribute {name!r}")
