"""Motion-time model of a Marlin printer: trapezoidal velocity profiles from the profile's limits.

Marlin caps a move's speed and acceleration so that no axis exceeds its own limit (M203, M201),
accelerates at the travel acceleration (M204 T) and, for the point-to-point moves of a probe plan,
starts and ends each move at rest. The same model times the fake firmware's moves and estimates how
long a probe plan takes on the real printer (`estimated_hardware_s`). Junction blending between
consecutive collinear moves is not modelled, so estimates err on the long side for chained moves.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

AXES = ("x", "y", "z")
Point = tuple[float, float, float]


@dataclass(frozen=True)
class Trapezoid:
    """A rest-to-rest move of `distance` mm: accelerate, cruise at `v_peak`, decelerate."""

    distance: float
    v_peak: float
    accel: float

    @property
    def t_accel(self) -> float:
        return self.v_peak / self.accel if self.distance > 0 else 0.0

    @property
    def t_cruise(self) -> float:
        if self.distance <= 0:
            return 0.0
        return (self.distance - self.v_peak * self.v_peak / self.accel) / self.v_peak

    @property
    def duration(self) -> float:
        return 2.0 * self.t_accel + self.t_cruise

    def distance_at(self, t: float) -> float:
        """Distance travelled `t` seconds after the move started (clamped to [0, distance])."""
        if t <= 0 or self.distance <= 0:
            return 0.0
        ta, tc = self.t_accel, self.t_cruise
        if t < ta:
            return 0.5 * self.accel * t * t
        d_acc = 0.5 * self.accel * ta * ta
        if t < ta + tc:
            return d_acc + self.v_peak * (t - ta)
        td = t - ta - tc
        if td >= ta:
            return self.distance
        return min(
            self.distance, d_acc + self.v_peak * tc + self.v_peak * td - 0.5 * self.accel * td * td
        )


def trapezoid(distance: float, feed: float, accel: float) -> Trapezoid:
    """The profile of a rest-to-rest move; a triangle when it is too short to reach `feed`."""
    if distance < 0 or feed <= 0 or accel <= 0:
        raise ValueError(
            f"need distance >= 0, feed > 0, accel > 0 (got {distance}, {feed}, {accel})"
        )
    if distance == 0:
        return Trapezoid(0.0, feed, accel)
    v_peak = min(feed, math.sqrt(distance * accel))
    return Trapezoid(float(distance), v_peak, float(accel))


class MotionModel:
    """Times moves and homing for one printer profile (mm, mm/s, mm/s², seconds)."""

    def __init__(self, profile: Mapping):
        self.max_feed = tuple(float(profile["max_feedrate_mm_s"][a]) for a in AXES)
        self.max_accel = tuple(float(profile["max_acceleration_mm_s2"][a]) for a in AXES)
        self.accel = float(profile["acceleration_mm_s2"])
        self.steps_per_mm = tuple(float(profile["steps_per_mm"][a]) for a in AXES)
        self.travel = tuple(float(profile["travel_mm"][a]) for a in AXES)
        self.home = tuple(float(profile.get("home_mm", {}).get(a, 0.0)) for a in AXES)
        self.homing_feed = tuple(float(profile["homing_feedrate_mm_s"][a]) for a in AXES)
        bump = profile.get("homing_bump_mm", {"x": 5, "y": 5, "z": 2})
        divisor = profile.get("homing_bump_divisor", {"x": 2, "y": 2, "z": 4})
        self.homing_bump = tuple(float(bump[a]) for a in AXES)
        self.homing_divisor = tuple(float(divisor[a]) for a in AXES)

    def limits(
        self, start: Sequence[float], end: Sequence[float], feed: float
    ) -> tuple[float, float]:
        """(speed, acceleration) along the path after Marlin's per-axis caps."""
        delta = [e - s for s, e in zip(start, end, strict=True)]
        length = math.sqrt(sum(d * d for d in delta))
        speed, accel = float(feed), self.accel
        if length == 0:
            return speed, accel
        for d, vmax, amax in zip(delta, self.max_feed, self.max_accel, strict=True):
            u = abs(d) / length
            if u > 0:
                speed = min(speed, vmax / u)
                accel = min(accel, amax / u)
        return speed, accel

    def move(self, start: Sequence[float], end: Sequence[float], feed: float) -> Trapezoid:
        speed, accel = self.limits(start, end, feed)
        length = math.dist(start, end)
        return trapezoid(length, speed, accel)

    def move_time(self, start: Sequence[float], end: Sequence[float], feed: float) -> float:
        return self.move(start, end, feed).duration

    def home_time(self, start: Sequence[float] | None = None) -> float:
        """G28 of all axes: approach each endstop, back off by the bump, re-approach slower.

        Marlin homes X, Y then Z, one axis at a time. From an unknown position (`None`, after a
        reset) assume the worst case: the full travel on every axis.
        """
        total = 0.0
        for i in range(3):
            dist = self.travel[i] if start is None else abs(start[i] - self.home[i])
            feed = self.homing_feed[i]
            accel = self.max_accel[i]
            bump = self.homing_bump[i]
            total += trapezoid(dist, feed, accel).duration  # approach the endstop
            total += trapezoid(bump, feed, accel).duration  # back off
            total += trapezoid(bump, feed / self.homing_divisor[i], accel).duration  # slow touch
        return total

    def plan_time(
        self,
        targets: Iterable[Sequence[float]],
        feed: float,
        start: Sequence[float] | None = None,
        home: bool = True,
    ) -> float:
        """Estimated seconds for optional homing then visiting `targets` (x, y, z) in order."""
        total = self.home_time(start) if home else 0.0
        here = tuple(self.home) if home or start is None else tuple(start)
        for target in targets:
            target = tuple(float(v) for v in target)
            total += self.move_time(here, target, feed)
            here = target
        return total

    def quantise(self, point: Sequence[float]) -> Point:
        """The position the steppers can reach: nearest whole step on each axis."""
        return tuple(round(p * s) / s for p, s in zip(point, self.steps_per_mm, strict=True))

    def steps(self, point: Sequence[float]) -> tuple[int, int, int]:
        return tuple(round(p * s) for p, s in zip(point, self.steps_per_mm, strict=True))
