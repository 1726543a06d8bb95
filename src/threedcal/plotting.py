"""Matplotlib for the library's figures: headless (the Agg backend, PNG out), imported only when a
figure is drawn, so the inference core never needs it."""

from __future__ import annotations


def pyplot():
    """matplotlib.pyplot on the Agg backend (no display needed)."""
    import matplotlib  # optional (workflow extra): loaded when a figure is drawn

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # only after the backend is chosen

    return plt
