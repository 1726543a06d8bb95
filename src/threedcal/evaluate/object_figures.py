"""Figures and tables of the test-object evaluation: Fig. 5 (depth maps and sections), Fig. 6
(violins of pixelwise errors) and a Table II-like markdown table. Matplotlib, Agg, PNG out."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from threedcal.errors import ConfigError
from threedcal.plotting import pyplot

_TYPES = ("Type 1", "Type 2")


def plot_error_violins(
    errors: pd.DataFrame, path: str | Path, *, title: str = "", max_points: int = 20_000
) -> Path:
    """Fig. 6: one violin per object and error type of the pixelwise errors (µm).

    `errors` is long: columns object, type (`Type 1` / `Type 2`), error_um (as
    :func:`threedcal.evaluate.object_errors.pixel_errors_um` gives). Large groups are thinned to
    `max_points` evenly spaced pixels (deterministic) for the density estimate.
    """
    missing = {"object", "type", "error_um"} - set(errors.columns)
    if missing:
        raise ConfigError(f"violin plot: error table lacks columns {sorted(missing)}")
    plt = pyplot()
    objects = list(dict.fromkeys(errors["object"]))
    fig, ax = plt.subplots(figsize=(1.8 + 1.6 * len(objects), 3.6))
    colors = {"Type 1": "tab:blue", "Type 2": "tab:orange"}
    for i, name in enumerate(objects):
        for j, kind in enumerate(_TYPES):
            values = errors.loc[(errors["object"] == name) & (errors["type"] == kind), "error_um"]
            values = values.to_numpy(dtype=float)
            values = values[np.isfinite(values)]
            if values.size < 2 or np.ptp(values) == 0:
                continue
            if values.size > max_points:
                values = values[np.linspace(0, values.size - 1, max_points).astype(int)]
            parts = ax.violinplot(
                values, positions=[i + (j - 0.5) * 0.38], widths=0.34, showmedians=True
            )
            for body in parts["bodies"]:
                body.set_facecolor(colors[kind])
                body.set_alpha(0.6)
    for kind in _TYPES:
        ax.plot([], [], color=colors[kind], lw=6, alpha=0.6, label=kind)
    ax.axhline(0, color="0.5", lw=0.8)
    ax.set_xticks(range(len(objects)), objects)
    ax.set_ylabel("predicted − ground truth (µm)")
    ax.legend(frameon=False, fontsize=8)
    ax.set_title(title)
    return _save(fig, path)


def plot_depth_sections(
    pred: np.ndarray,
    gt: np.ndarray,
    path: str | Path,
    *,
    px_per_mm: float,
    row: int | None = None,
    col: int | None = None,
    title: str = "",
) -> Path:
    """Fig. 5: predicted and ground-truth depth maps, and two perpendicular sections through them.

    The sections default to the row and column of the ground truth's deepest point.
    """
    pred = np.asarray(pred, dtype=float)
    gt = np.asarray(gt, dtype=float)
    if pred.shape != gt.shape or pred.ndim != 2:
        raise ConfigError(f"depth sections need two 2D maps of one shape: {pred.shape}, {gt.shape}")
    deepest = np.unravel_index(int(np.argmax(gt)), gt.shape)
    row = int(deepest[0] if row is None else row)
    col = int(deepest[1] if col is None else col)
    if not (0 <= row < gt.shape[0] and 0 <= col < gt.shape[1]):
        raise ConfigError(f"section row {row} / column {col} outside the image {gt.shape}")
    plt = pyplot()
    fig, axes = plt.subplots(2, 2, figsize=(8.5, 6.8), layout="constrained")  # no label overlaps
    vmax = max(float(np.nanmax(gt)), float(np.nanmax(pred)), 1e-6)
    h, w = gt.shape
    extent = (-0.5 / px_per_mm, (w - 0.5) / px_per_mm, (h - 0.5) / px_per_mm, -0.5 / px_per_mm)
    for ax, image, name in ((axes[0, 0], pred, "prediction"), (axes[0, 1], gt, "ground truth")):
        shown = ax.imshow(image, cmap="viridis", vmin=0, vmax=vmax, extent=extent)
        ax.axhline(row / px_per_mm, color="w", lw=0.8, ls="--")
        ax.axvline(col / px_per_mm, color="w", lw=0.8, ls=":")
        ax.set_title(f"{name} depth (mm)")
        ax.set_xlabel("x (mm)")
        ax.set_ylabel("y (mm)")
    fig.colorbar(shown, ax=axes[0, :].tolist(), shrink=0.8)
    for ax, cut, label, style in (
        (axes[1, 0], np.s_[row, :], f"row y = {row / px_per_mm:.2f} mm", "--"),
        (axes[1, 1], np.s_[:, col], f"column x = {col / px_per_mm:.2f} mm", ":"),
    ):
        coords = np.arange(pred[cut].size) / px_per_mm
        ax.plot(coords, gt[cut], color="k", lw=1.5, label="ground truth")
        ax.plot(coords, pred[cut], color="tab:red", lw=1.0, ls=style, label="prediction")
        ax.invert_yaxis()  # depth into the gel points down, as a profile of the surface
        ax.set_title(label)
        ax.set_xlabel("mm")
        ax.set_ylabel("depth (mm)")
        ax.legend(frameon=False, fontsize=8)
    fig.suptitle(title)
    return _save(fig, path)


def plot_depth_preview(
    depth: np.ndarray, path: str | Path, *, px_per_mm: float, title: str = ""
) -> Path:
    """One ground-truth depth map in mm, for the exported objects."""
    plt = pyplot()
    h, w = depth.shape
    fig, ax = plt.subplots(figsize=(4.5, 4.5 * h / w + 0.6))
    extent = (-0.5 / px_per_mm, (w - 0.5) / px_per_mm, (h - 0.5) / px_per_mm, -0.5 / px_per_mm)
    shown = ax.imshow(depth, cmap="viridis", vmin=0, extent=extent)
    fig.colorbar(shown, ax=ax, label="depth (mm)")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.set_title(title)
    return _save(fig, path)


def table_ii_markdown(
    errors: pd.DataFrame,
    *,
    p: int = 80,
    by: str = "scene",
    metrics: Sequence[str] = ("overall_um", "type1_um", "type2_um"),
    protocol: str = "printer",
) -> str:
    """Table II: one row per object, one column group per `by` value (sensor or scene), MAE in µm.

    `errors` holds rows of `objects/errors.csv` with a `by` column added; only fraction `p` and,
    where the table has a `protocol` column, that protocol (`printer` or `paper`) are used.
    """
    needed = {"object", "P", by, *metrics}
    if needed - set(errors.columns):
        raise ConfigError(
            f"Table II: error table lacks columns {sorted(needed - set(errors.columns))}"
        )
    chosen = errors[errors["P"] == p]
    heading = f"MAE in µm at P = {p} %."
    if "protocol" in errors.columns:
        chosen = chosen[chosen["protocol"] == protocol]
        heading = f"MAE in µm at P = {p} %, {protocol} protocol."
    if chosen.empty:
        raise ConfigError(
            f"Table II: no rows with P = {p} and protocol {protocol!r} "
            f"(have P {sorted(set(errors['P']))})"
        )
    groups = list(dict.fromkeys(chosen[by]))
    names = {"overall_um": "overall", "type1_um": "Type 1", "type2_um": "Type 2"}
    header = ["object"] + [f"{g} {names.get(m, m)}" for g in groups for m in metrics]
    lines = [
        heading,
        "",
        "| " + " | ".join(header) + " |",
        "|" + "|".join(["---"] + ["---:"] * (len(header) - 1)) + "|",
    ]
    for name in dict.fromkeys(chosen["object"]):
        cells = [str(name)]
        for g in groups:
            row = chosen[(chosen["object"] == name) & (chosen[by] == g)]
            for m in metrics:
                value = float(row[m].mean()) if len(row) else float("nan")
                cells.append("—" if not np.isfinite(value) else f"{value:.0f}")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def _save(fig, path: str | Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120, bbox_inches="tight")
    pyplot().close(fig)
    return path


def plot_pill_by_fraction(maps: Mapping[int, np.ndarray], path: str | Path) -> None:
    """Fig. 3C: the pill's predicted depth for every training fraction P."""
    plt = pyplot()

    fractions = sorted(maps)
    vmax = max(float(np.nanmax(m)) for m in maps.values()) or 1.0
    fig, axes = plt.subplots(
        1, len(fractions), figsize=(2.2 * len(fractions), 3.0), dpi=110, squeeze=False
    )
    for ax, p in zip(axes[0], fractions, strict=True):
        shown = ax.imshow(maps[p], cmap="viridis", vmin=0, vmax=vmax)
        ax.set_title(f"P = {p} %", fontsize=9)
        ax.axis("off")
    fig.colorbar(shown, ax=axes[0].tolist(), shrink=0.8, label="depth (mm)")
    fig.suptitle("pill: predicted depth by training fraction (first reporting press)")
    fig.savefig(path)
    plt.close(fig)
