"""Test objects on the simulated bench, evaluated as in the paper (Sec. IV, Table II, Figs. 3C, 5, 6).

A person presses each object into the sensor by hand: off-centre, turned a little, a little deeper or
shallower than meant. The bench does the same from the scene's seed, renders the frame with the gel
simulator, and every model of the scene (P = 80 for the figures) predicts depth; the ground truth from the CAD
mesh is aligned to the prediction in x, y, its depth fitted, and the errors split into Type 1
(ground truth 0) and Type 2 (in contact).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from threedcal.errors import ConfigError
from threedcal.evaluate.groundtruth import check_indentation, surface_height
from threedcal.evaluate.objects import load_object, object_label


@dataclass(frozen=True)
class Press:
    """One simulated manual press: where, how turned, how deep (truth), and what was meant."""

    name: str
    center_px: tuple[float, float]
    rotation_deg: float
    depth_mm: float
    nominal_depth_mm: float
    number: int = 0  # which of the object's presses (0 first)


def plan_presses(
    objects: Sequence[str], shape: tuple[int, int], pressing: Mapping, seed: int
) -> list[Press]:
    """Each object pressed `presses` times, each off-centre (up to `offset_fraction` of the frame),
    turned up to `rotation_deg`, to the nominal depth ± `depth_jitter` (a fraction).

    Round by round (every object once, then again): more presses keep the earlier ones."""
    rng = np.random.default_rng([seed, 0x0B1EC7])
    height, width = shape
    presses = []
    for number in range(int(pressing["presses"])):
        for ref in objects:
            dx, dy = rng.uniform(-1, 1, 2) * pressing["offset_fraction"] * np.array([width, height])
            nominal = float(pressing["depth_mm"])
            presses.append(
                Press(
                    name=str(ref),
                    center_px=((width - 1) / 2 + float(dx), (height - 1) / 2 + float(dy)),
                    rotation_deg=float(rng.uniform(-1, 1) * pressing["rotation_deg"]),
                    depth_mm=nominal * (1 + float(rng.uniform(-1, 1)) * pressing["depth_jitter"]),
                    nominal_depth_mm=nominal,
                    number=number,
                )
            )
    return presses


def relief_indenter(mesh, px_per_mm: float, rotation_deg: float):
    """The mesh as the simulator's height-map indenter: protrusion toward the gel (mm), NaN outside."""
    from threedcal.sim.indenters import HeightMap

    extent = float(np.ptp(mesh.vertices[:, :2], axis=0).max())
    size = int(math.ceil(extent * math.sqrt(2) * px_per_mm)) + 5
    surface = surface_height(
        mesh, (size, size), px_per_mm, ((size - 1) / 2, (size - 1) / 2), rotation_deg
    )
    relief = np.where(surface.covered, -surface.height_mm, np.nan)
    return HeightMap(relief, px_per_mm)


def render_press(simulator, press: Press, frame_index: int = 0) -> np.ndarray:
    mesh = load_object(press.name)
    check_indentation(press.depth_mm, simulator.max_penetration_mm)
    indenter = relief_indenter(mesh, simulator.px_per_mm, press.rotation_deg)
    return simulator.render(indenter, press.center_px, 0.0, press.depth_mm, frame_index=frame_index)


def _estimator_frame(estimator, frame: np.ndarray) -> np.ndarray:
    """The frame at the resolution the model was trained on (datasets may be downscaled)."""
    if frame.shape[:2] == estimator.image_shape:
        return frame
    import cv2

    height, width = estimator.image_shape
    return cv2.resize(frame, (width, height), interpolation=cv2.INTER_AREA)


def evaluate_objects(
    scene: Mapping,
    models: Mapping[int, str | Path],
    out_dir: str | Path,
    *,
    progress: bool = True,
) -> pd.DataFrame:
    """Render every press, predict with every model, score; write tables and figures into `out_dir`.

    errors.csv has a row per object and P: the mean over the object's presses (presses.csv has
    each). The integrator comparison and the violins (Fig. 6) use the P = 80 model and every
    press; the sections (Fig. 5) and Fig. 3C (the pill at every P) the first press.
    """
    from tqdm import tqdm

    from threedcal.evaluate.object_errors import ERROR_COLUMNS, evaluate_press, pixel_errors_um
    from threedcal.evaluate.object_figures import plot_depth_sections, plot_error_violins
    from threedcal.model.inference import DepthEstimator
    from threedcal.profiles import load_profile
    from threedcal.sim.optics import GelSimulator

    out_dir = Path(out_dir)
    figures = out_dir / "figures"
    figures.mkdir(parents=True, exist_ok=True)
    sensor = load_profile("sensor", scene["sensor"])
    if sensor["type"] != "vision":
        raise ConfigError(
            f"test objects need a vision sensor; {sensor['name']} is {sensor['type']}"
        )
    simulator = GelSimulator(sensor, seed=scene["seed"])
    shape = (simulator.height, simulator.width)
    presses = plan_presses(scene["objects"], shape, scene["pressing"], scene["seed"])
    integrators = list(scene["integrators"])
    full = max(models)
    estimators = {
        p: DepthEstimator.from_checkpoint(path, device="cpu") for p, path in models.items()
    }
    rows, pixel_tables, comparison = [], [], []
    pill_maps: dict[int, np.ndarray] = {}
    for index, press in enumerate(tqdm(presses, desc="objects", unit="obj", disable=not progress)):
        label = object_label(press.name)
        frame = render_press(simulator, press, frame_index=index)
        mesh = load_object(press.name)
        fractions = sorted(models)
        for p in fractions:
            estimator = estimators[p]
            image = _estimator_frame(estimator, frame)
            for k, method in enumerate(integrators if p == full else integrators[:1]):
                depth = estimator.depth(image, method=method)
                scale = estimator.px_per_mm / simulator.px_per_mm
                evaluation = evaluate_press(
                    depth,
                    mesh,
                    px_per_mm=estimator.px_per_mm,
                    nominal_indentation_mm=press.nominal_depth_mm,
                    max_penetration_mm=simulator.max_penetration_mm,
                    center_px=(
                        (press.center_px[0] + 0.5) * scale - 0.5,
                        (press.center_px[1] + 0.5) * scale - 0.5,
                    ),
                    rotation_deg=press.rotation_deg,
                )
                errors = evaluation.errors
                row = {
                    "object": label,
                    "press": press.number,
                    "P": p,
                    **{m: errors[m] for m in ERROR_COLUMNS[2:]},
                    "fitted_depth_mm": evaluation.indentation_mm,
                    "true_depth_mm": press.depth_mm,
                }
                comparison.append({**row, "integrator": method})
                if k > 0:
                    continue
                rows.append(
                    {
                        **row,
                        "center_x_px": press.center_px[0],
                        "center_y_px": press.center_px[1],
                        "rotation_deg": press.rotation_deg,
                    }
                )
                if p == full:
                    pixel_tables.append(pixel_errors_um(label, depth, evaluation.gt_mm))
                if p == full and press.number == 0:
                    plot_depth_sections(
                        depth,
                        evaluation.gt_mm,
                        figures / f"{label}_sections.png",
                        px_per_mm=estimator.px_per_mm,
                        title=f"{label}: P = {p} %, {method}",
                    )
                if label == "pill" and press.number == 0:
                    pill_maps[p] = depth
    per_press = pd.DataFrame(rows)
    per_press.to_csv(out_dir / "presses.csv", index=False)
    errors = (
        per_press.groupby(["object", "P"], sort=False)[list(ERROR_COLUMNS[2:])]
        .mean()
        .reset_index()[list(ERROR_COLUMNS)]
    )
    errors.to_csv(out_dir / "errors.csv", index=False)
    pd.DataFrame(comparison).to_csv(out_dir / "integrators.csv", index=False)
    if pixel_tables:
        plot_error_violins(
            pd.concat(pixel_tables),
            out_dir / "violins.png",
            title=f"pixelwise depth errors, P = {full} %",
        )
    if pill_maps:
        pill_figure(pill_maps, figures / "pill_by_P.png")
    return errors


def pill_figure(maps: Mapping[int, np.ndarray], path: str | Path) -> None:
    """Fig. 3C: the pill's predicted depth for every training fraction P."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

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
    fig.suptitle("pill: predicted depth by training fraction")
    fig.savefig(path)
    plt.close(fig)
