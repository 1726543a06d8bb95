"""When a training ends: the paper's fixed epochs, or when the error on data it may see stops falling.

`epochs` (the paper's rule, `config/paper.yaml`): epochs_base · 80 / P epochs, whatever the error
does. A budget says nothing about whether a model has learnt what its data can teach it: the
ablation then compares how far each model got, not what its data holds.

`plateau`: a share of the model's *own* training coordinates (`holdout`, drawn per replicate) is
set aside and never trained on; the error on it is checked every `check_every` optimiser steps
(at the end of the epoch in which the count passes the mark). When `patience` checks in a row
have not lowered the best error by more than `min_improvement` (relative), the learning rate
drops by `drop_factor` and training goes on from the best weights; after `lr_drops` drops (or at
`max_steps`) it stops, and the best weights are the model. The stats stage's validation
coordinates are never among the checked ones, so the figures it reports chose nothing here.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from threedcal.errors import ConfigError

RULES = ("epochs", "plateau")


def holdout_split(indices: np.ndarray, fraction: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(fit, holdout) of a model's training frames: `fraction` of them (at least one, and only
    when three or more remain to fit on) drawn with the replicate's seed, both sorted."""
    indices = np.asarray(indices)
    n_hold = int(round(fraction * len(indices)))
    if fraction > 0:
        n_hold = max(n_hold, 1)
    if len(indices) - n_hold < 2 or n_hold == 0:
        return np.sort(indices), indices[:0]
    order = np.random.default_rng([int(seed), 0x5EED]).permutation(len(indices))
    return np.sort(indices[order[n_hold:]]), np.sort(indices[order[:n_hold]])


@dataclass
class Plateau:
    """The `plateau` rule's state (a resumed training restores it: `state` / `from_state`)."""

    lr: float
    check_every: int
    patience: int
    min_improvement: float
    lr_drops: int
    drop_factor: float
    max_steps: int
    min_steps: int = 0
    best: float = math.inf
    best_step: int = 0
    stale: int = 0  # checks since the best improved by more than min_improvement
    drops: int = 0
    next_check: int = 0
    done: bool = False
    reason: str = ""
    history: list = field(default_factory=list)

    @classmethod
    def of(cls, stopping: Mapping, lr: float, scale: float = 1.0, min_steps: int = 0) -> Plateau:
        """The rule of a scene's `model.stopping`; `scale` stretches its patience and step cap
        (a longer budget: twice the patience to find an improvement, twice the steps)."""
        if scale <= 0:
            raise ConfigError(f"a stopping rule's budget scale must be positive, got {scale}")
        return cls(
            lr=float(lr),
            check_every=int(stopping["check_every"]),
            patience=max(1, int(round(stopping["patience"] * scale))),
            min_improvement=float(stopping["min_improvement"]),
            lr_drops=int(stopping["lr_drops"]),
            drop_factor=float(stopping["drop_factor"]),
            max_steps=int(round(stopping["max_steps"] * scale)),
            min_steps=int(min_steps),
            next_check=int(stopping["check_every"]),
        )

    @property
    def current_lr(self) -> float:
        return self.lr * self.drop_factor**self.drops

    def due(self, step: int) -> bool:
        return step >= self.next_check or step >= self.max_steps

    def observe(self, step: int, error: float) -> tuple[bool, bool]:
        """Take the holdout error at `step`: (improved: keep these weights as the best,
        dropped: the rate fell, go on from the best weights)."""
        if not math.isfinite(error):
            raise ConfigError(f"the holdout error at step {step} is {error}")
        self.next_check = step + self.check_every
        self.history.append([int(step), float(error)])
        improved = error < self.best
        if error < self.best * (1 - self.min_improvement):
            self.stale = 0
        else:
            self.stale += 1
        if improved:
            self.best, self.best_step = float(error), int(step)
        dropped = False
        if step >= self.max_steps and step >= self.min_steps:
            self.done, self.reason = True, f"reached max_steps ({self.max_steps})"
        elif self.stale >= self.patience and step >= self.min_steps:
            if self.drops >= self.lr_drops:
                self.done = True
                self.reason = (
                    f"the holdout error stopped falling ({self.patience} checks without a "
                    f"{self.min_improvement:.0%} gain after {self.drops} learning-rate drops)"
                )
            else:
                self.drops += 1
                self.stale = 0
                dropped = True
        return improved, dropped

    def state(self) -> dict:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}

    @classmethod
    def from_state(cls, state: Mapping) -> Plateau:
        return cls(**{k: state[k] for k in cls.__dataclass_fields__ if k in state})


def check_rule(stopping: Mapping, where: str = "model.stopping") -> None:
    if stopping.get("rule") not in RULES:
        raise ConfigError(f"{where}.rule: {stopping.get('rule')!r} (allowed: {', '.join(RULES)})")
