"""Matplotlib for the library's figures: headless (the Agg backend, PNG out), imported only when a
figure is drawn, so the inference core never needs it."""

from __future__ import annotations


def pyplot():
    """matplotlib.pyplot on the Agg backend (no display needed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt
