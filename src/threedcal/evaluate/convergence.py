"""Has each model learnt what its data can teach it? Error against training time, to twice the budget.

The ablation compares fractions P by their models' validation error; that comparison is about the
data only if every model has finished learning. So P = 80 % and the smallest P (replicate 0) are
trained again under the same stopping rule with twice its budget (twice the patience and step cap,
and at least twice the steps the study's model took), keeping a snapshot of the best weights at
every check. Each snapshot is scored as the stats stage scores the study's models (mean validation
MSE per coordinate): `error_vs_time.csv` is the curve, `convergence.csv` compares the study's
model with the longer training's. The validation coordinates chose nothing here: they only score.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import pandas as pd

from threedcal.dataset.trainset import TrainingSet
from threedcal.evaluate.validation import coordinate_mse
from threedcal.plotting import pyplot

CURVE_COLUMNS = ("P", "run", "steps", "seconds", "mse")
CONVERGENCE_COLUMNS = (
    "P",
    "study_steps",
    "study_seconds",
    "study_mse",
    "twice_steps",
    "twice_seconds",
    "twice_mse",
    "change",
)


def _score(checkpoint: Mapping, trainset: TrainingSet) -> float:
    from threedcal.model.inference import DepthEstimator

    estimator = DepthEstimator(dict(checkpoint), device="cpu")
    return float(coordinate_mse(estimator, trainset)["mse"].mean())


def seconds_at(losses: pd.DataFrame) -> pd.Series:
    """Training seconds spent to reach each logged step (losses.csv: seconds since the last row)."""
    return pd.Series(losses["seconds"].cumsum().to_numpy(), index=losses["step"].to_numpy())


def curve_table(
    study: Mapping[int, tuple[str | Path, str | Path]],
    twice: Mapping[int, tuple[str | Path, str | Path]],
    trainset: TrainingSet,
) -> pd.DataFrame:
    """Every snapshot of the longer trainings and the study's own models, scored. `study` and
    `twice` map P to (model.pt or snapshots/, losses.csv)."""
    from threedcal.model.checkpoint import read_checkpoint

    rows = []
    for p in sorted(study):
        model_path, losses_path = study[p]
        model = read_checkpoint(model_path)
        clock = seconds_at(pd.read_csv(losses_path))
        steps = int(model["training"]["steps"])
        rows.append(_point(p, "study", steps, clock, _score(model, trainset)))
        snapshots, losses_path = twice[p]
        clock = seconds_at(pd.read_csv(losses_path))
        for path in sorted(Path(snapshots).glob("step*.pt")):
            snapshot = read_checkpoint(path)
            steps = int(snapshot["training"]["steps"])
            rows.append(_point(p, "twice", steps, clock, _score(snapshot, trainset)))
    return pd.DataFrame(rows, columns=list(CURVE_COLUMNS))


def _point(p: int, run: str, steps: int, clock: pd.Series, mse: float) -> dict:
    seconds = float(clock.loc[steps]) if steps in clock.index else float("nan")
    return {"P": int(p), "run": run, "steps": steps, "seconds": seconds, "mse": mse}


def convergence_table(curve: pd.DataFrame) -> pd.DataFrame:
    """Per P: the study's model against the longer training's last (best) snapshot."""
    rows = []
    for p, runs in curve.groupby("P"):
        study = runs[runs["run"] == "study"].iloc[0]
        twice = runs[runs["run"] == "twice"].sort_values("steps").iloc[-1]
        rows.append(
            {
                "P": int(p),
                "study_steps": int(study["steps"]),
                "study_seconds": float(study["seconds"]),
                "study_mse": float(study["mse"]),
                "twice_steps": int(twice["steps"]),
                "twice_seconds": float(twice["seconds"]),
                "twice_mse": float(twice["mse"]),
                "change": float(twice["mse"] / study["mse"] - 1.0),
            }
        )
    return pd.DataFrame(rows, columns=list(CONVERGENCE_COLUMNS))


def curve_figure(curve: pd.DataFrame, path: str | Path, title: str) -> None:
    """Validation MSE against training seconds per P; the study's model marked where it stopped."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6, 3.6), dpi=120)
    colours = ("tab:blue", "tab:orange", "tab:green", "tab:red")
    for index, (p, runs) in enumerate(curve.groupby("P")):
        colour = colours[index % len(colours)]
        twice = runs[runs["run"] == "twice"].sort_values("seconds")
        ax.plot(twice["seconds"], twice["mse"], "-o", ms=3, color=colour, label=f"P = {p} %")
        study = runs[runs["run"] == "study"].iloc[0]
        ax.axvline(study["seconds"], color=colour, ls=":", lw=1)
        ax.plot([study["seconds"]], [study["mse"]], "*", ms=12, color=colour, mec="k", mew=0.6)
    ax.set_xlabel("training time (s, the best weights so far)")
    ax.set_ylabel("mean validation MSE")
    ax.set_title(title, fontsize=10)
    ax.text(
        0.99,
        0.97,
        "star, dotted: the study's model and its budget\nline: the same training, twice the budget",
        transform=ax.transAxes,
        ha="right",
        va="top",
        fontsize=7,
    )
    ax.legend(loc="lower left", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, metadata={"Software": None})
    plt.close(fig)
