"""When a training ends: the paper's fixed epochs, or when twice the training no longer pays.

`epochs` (the paper's rule, `config/paper.yaml`): epochs_base · 80 / P epochs, whatever the error
does. A budget says nothing about whether a model has learnt what its data can teach it: the
ablation then compares how far each model got, not what its data holds.

`doubling`: a share of the model's *own* training coordinates (`holdout`, drawn per replicate) is
set aside and never trained on. Training runs in cycles, each a half cosine of the rate from `lr`
down to lr/100, the first `first_cycle` steps long and every later one as long as all before it, so
that after each cycle the training has doubled. After each cycle the error on the holdout is
checked: when a cycle has not lowered the best error by more than `min_gain` (relative), twice the
training no longer pays and it stops; it also stops once it has taken `max_steps`. The best weights
checked are the model (for a small fraction that starts to overfit, an early cycle's). The stats
stage's validation coordinates are never among the checked ones, so the errors it reports chose
nothing here.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from threedcal.errors import ConfigError

RULES = ("epochs", "doubling")
# The ablation's fixed budget (threedcal.model.lockstep) runs the doubling rule's cycles from a
# quarter of it, with no stop: they end at 1/4, 1/2 and all of it.
FIRST_CYCLE_SHARE = 4
# In a training's folder: the weights at earlier cycle ends, and the model at twice the budget.
SNAPSHOT_DIR = "snapshots"
TWICE_DIR = "twice"


def snapshot_name(steps: int) -> str:
    return f"step{int(steps):07d}.pt"


def cycle_ends(budget: int, twice: bool = False) -> list[int]:
    """Steps at which the ablation's cycles end: budget/4, budget/2, budget (then 2 x budget)."""
    if int(budget) < FIRST_CYCLE_SHARE:
        raise ConfigError(f"ablation.steps: {budget} (at least {FIRST_CYCLE_SHARE})")
    budget = int(budget)
    ends = [budget // 4, budget // 2, budget]
    return ends + [2 * budget] if twice else ends


def holdout_split(
    indices: np.ndarray, fraction: float, seed: int, points: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """(fit, holdout) of a model's training frames, both sorted: `fraction` of its probe
    coordinates (`points`, one per frame; None: each frame its own), at least one, and only when
    two or more remain to fit on, drawn with the replicate's seed. Every frame of a held-out
    coordinate is held out, so no pressed spot is both fitted and judged."""
    indices = np.asarray(indices)
    points = indices if points is None else np.asarray(points)
    coordinates = np.unique(points)
    n_hold = int(round(fraction * len(coordinates)))
    if fraction > 0:
        n_hold = max(n_hold, 1)
    if len(coordinates) - n_hold < 2 or n_hold == 0:
        return np.sort(indices), indices[:0]
    order = np.random.default_rng([int(seed), 0x5EED]).permutation(len(coordinates))
    held = np.isin(points, coordinates[order[:n_hold]])
    return np.sort(indices[~held]), np.sort(indices[held])


@dataclass
class Doubling:
    """The `doubling` rule's state (a resumed training restores it: `state` / `from_state`)."""

    lr: float
    first_cycle: int
    min_gain: float
    max_steps: int
    min_steps: int = 0
    cycle: int = 0  # cycles finished
    steps: int = 0  # steps at the end of the last finished cycle
    best: float = math.inf
    best_step: int = 0
    done: bool = False
    reason: str = ""
    history: list = field(default_factory=list)

    @classmethod
    def of(cls, stopping: Mapping, lr: float, scale: float = 1.0, min_steps: int = 0) -> Doubling:
        """The rule of a scene's `model.stopping`; `scale` stretches its step cap (the
        convergence check: twice the budget), `min_steps` forbids stopping before that many."""
        if scale <= 0:
            raise ConfigError(f"a stopping rule's budget scale must be positive, got {scale}")
        return cls(
            lr=float(lr),
            first_cycle=int(stopping["first_cycle"]),
            min_gain=float(stopping["min_gain"]),
            max_steps=int(round(stopping["max_steps"] * scale)),
            min_steps=int(min_steps),
        )

    def next_cycle(self) -> int:
        """Steps of the cycle to come: the first's, then as many as all before it; cut at
        max_steps (and stretched to reach min_steps when that is what keeps it going)."""
        length = self.first_cycle if self.cycle == 0 else self.steps
        cap = max(self.max_steps, self.min_steps)
        return max(1, min(length, cap - self.steps))

    def lr_at(self, step_in_cycle: int, length: int) -> float:
        """A half cosine from lr to lr/100 over the cycle, step by step."""
        floor = self.lr / 100
        return floor + (self.lr - floor) * 0.5 * (1 + math.cos(math.pi * step_in_cycle / length))

    def observe(self, steps: int, error: float) -> bool:
        """Take the holdout error after a cycle that ended at `steps`: True when these weights
        are the best so far (keep them)."""
        if not math.isfinite(error):
            raise ConfigError(f"the holdout error after {steps} steps is {error}")
        self.history.append([int(steps), float(error)])
        gained = error < self.best * (1 - self.min_gain)
        improved = error < self.best
        self.cycle, self.steps = self.cycle + 1, int(steps)
        if improved:
            self.best, self.best_step = float(error), int(steps)
        if steps < self.min_steps:
            return improved
        if steps >= max(self.max_steps, self.min_steps):
            self.done, self.reason = True, f"reached max_steps ({self.max_steps})"
        elif not gained:
            self.done = True
            self.reason = (
                f"doubling the training to {steps} steps lowered the holdout error by less "
                f"than {self.min_gain:.0%}"
            )
        return improved

    def state(self) -> dict:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}

    @classmethod
    def from_state(cls, state: Mapping) -> Doubling:
        return cls(**{k: state[k] for k in cls.__dataclass_fields__ if k in state})


def check_rule(stopping: Mapping, where: str = "model.stopping") -> None:
    if stopping.get("rule") not in RULES:
        raise ConfigError(f"{where}.rule: {stopping.get('rule')!r} (allowed: {', '.join(RULES)})")
