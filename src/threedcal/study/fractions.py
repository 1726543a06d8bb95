"""Which data fractions P a scene trains models for, and how many replicates of each: the scene's
`ablation` setting in its full form, read the same way by the dataset stage, the workflow and the
report."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from threedcal.schema import load_schema

# The one fraction trained when a scene asks for no ablation: all training coordinates (80 % of all).
FULL_TRAINING_P = 80


def normalise_ablation(ablation: Any) -> dict:
    """`ablation` in its full form {fractions, replicates, steps, convergence, batching}.

    The plain list form [1, 5, ..., 80] (and no `ablation` at all) means one replicate; the
    schema's defaults fill what a mapping leaves out.
    """
    defaults = load_schema("config")["$defs"]["ablation"]["oneOf"][1]["properties"]
    full = {key: spec["default"] for key, spec in defaults.items() if "default" in spec}
    if not ablation:
        return {**full, "fractions": []}
    if isinstance(ablation, Mapping):
        full.update({k: v for k, v in ablation.items() if v is not None})
        return {
            **full,
            "fractions": list(full.get("fractions") or []),
            "replicates": int(full["replicates"]),
            "steps": int(full["steps"]),
            "convergence": bool(full["convergence"]),
        }
    return {**full, "fractions": list(ablation)}


def training_fractions(scene: Mapping) -> list[int]:
    """The fractions P (percent) for which a scene trains models, ascending."""
    return sorted(normalise_ablation(scene.get("ablation"))["fractions"] or [FULL_TRAINING_P])


def ablation_replicates(scene: Mapping) -> int:
    """R: models per fraction, each a fresh nested subset draw and a fresh initialisation."""
    return normalise_ablation(scene.get("ablation"))["replicates"]


def convergence_fractions(scene: Mapping) -> list[int]:
    """The fractions whose models train on to twice the budget (ablation.convergence): every
    fraction of an ablation with the option; none without it or an ablation."""
    ablation = normalise_ablation(scene.get("ablation"))
    fractions = training_fractions(scene)
    if not ablation["convergence"] or len(fractions) < 2 or FULL_TRAINING_P not in fractions:
        return []
    return fractions


def model_keys(scene: Mapping) -> list[tuple[int, int]]:
    """Every (P, replicate) a scene trains: one training job each."""
    return [(p, r) for p in training_fractions(scene) for r in range(ablation_replicates(scene))]
