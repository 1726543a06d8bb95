"""Units of one sensor model that differ as manufactured units do: the profile's constants drawn
around their values by the spreads of its `unit_variation` block.

Two DIGITs or two GelSight Minis of one design do not image a press alike: their LEDs sit and
diffuse differently, their gels are poured thicker or softer, their cameras blur and noise
differently. A model trained on one unit is then a poor start for the next; one trained on many
draws of this variation is a start for any. `draw_unit(profile, seed)` is one such unit: the same
seed always gives the same unit. Where the camera sits (the seating in the printed base) and its
lens are drawn by the bench itself (threedcal.sim.bench), per seed, for every unit.

Beyond scaling the profile's own constants, a unit may get a background field of its own
(`background_field_dn`: a random smooth field of that rms added to the profile's) and a skin of
its own (`skin_tension_range_n_per_mm`: its tension drawn uniformly in that range, for a profile
whose halo is not pinned by a skin of its own). `smooth_field_coefficients` draws such a field;
the pretraining presses use it too, for the drift of a frame's light from its blank.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Mapping

import numpy as np
from numpy.polynomial import legendre

from threedcal.errors import ConfigError

# Unit seeds are drawn apart from the bench's other streams (noise, seating) of the same number.
_STREAM = 0x0417
# A unit's own background field (`background_field_dn`): a smooth field of this degree, as the
# fitted DIGIT field's (optics.background_field), drawn apart from the unit's other constants.
FIELD_DEGREE = 4
_FIELD_STREAM = 0x0F1E


def draw_unit(profile: Mapping, seed: int | None) -> dict:
    """The profile of unit `seed` (None: the profile itself, unchanged)."""
    if seed is None:
        return dict(profile)
    if profile.get("type") != "vision":
        raise ConfigError(
            f"sensor profile {profile.get('name')!r}: units are drawn for vision sensors"
        )
    spread = profile.get("unit_variation") or {}
    if not spread:
        raise ConfigError(
            f"sensor profile {profile.get('name')!r} has no unit_variation block: give one "
            "(docs/explanation/simulator.md#unit-to-unit-variation) to draw units of it"
        )
    rng = np.random.default_rng([int(seed), _STREAM])
    unit = copy.deepcopy(dict(profile))
    unit["lights"] = [_light(light, spread, rng) for light in unit["lights"]]
    unit["optics"] = _optics(unit["optics"], spread, rng)
    unit["gel"] = _gel(unit["gel"], spread, rng)
    field_dn = float(spread.get("background_field_dn", 0) or 0)
    if field_dn > 0:
        own = np.random.default_rng([int(seed), _STREAM, _FIELD_STREAM])
        unit["optics"]["background_field"] = _with_field(
            unit["optics"].get("background_field"), smooth_field_coefficients(own, field_dn)
        )
    return unit


def legendre_terms(degree: int) -> list[tuple[int, int]]:
    """(i, j) of the products P_i(u) P_j(v), 0 < i + j <= degree: the non-constant terms."""
    return [(k - j, j) for k in range(1, degree + 1) for j in range(k + 1)]


def smooth_field_coefficients(
    rng: np.random.Generator, rms_dn: float, degree: int = FIELD_DEGREE
) -> np.ndarray:
    """(3, T) coefficients in threedcal.sim.background_field.field_terms' monomial basis of a random smooth
    field per channel whose mean square over the frame (u, v uniform in -1..1) is rms_dn² in
    expectation and whose mean is zero: independent normal weights on the normalised Legendre
    products sqrt((2i+1)(2j+1)) P_i(u) P_j(v), each of which has mean 0 and mean square 1."""

    pairs = legendre_terms(degree)
    weights = rng.normal(0.0, float(rms_dn) / math.sqrt(len(pairs)), (3, len(pairs)))
    order = [(k - j, j) for k in range(degree + 1) for j in range(k + 1)]  # field_terms' order
    index = {power: n for n, power in enumerate(order)}
    basis = np.zeros((len(pairs), len(order)))
    for t, (i, j) in enumerate(pairs):
        pu = legendre.leg2poly(np.eye(i + 1)[i]) * math.sqrt(2 * i + 1)
        pv = legendre.leg2poly(np.eye(j + 1)[j]) * math.sqrt(2 * j + 1)
        for a, ca in enumerate(pu):
            for b, cb in enumerate(pv):
                basis[t, index[(a, b)]] += ca * cb
    return weights @ basis


def _with_field(field: Mapping | None, extra: np.ndarray) -> dict:
    """The profile's background_field (or none) plus `extra` coefficients of degree FIELD_DEGREE."""
    if not field:
        return {"degree": FIELD_DEGREE, "coefficients_dn": extra.tolist()}
    degree = max(int(field["degree"]), FIELD_DEGREE)
    size = (degree + 1) * (degree + 2) // 2
    total = np.zeros((3, size))
    own = np.asarray(field["coefficients_dn"], float)
    total[:, : own.shape[1]] += own  # field_terms lists lower degrees first
    total[:, : extra.shape[1]] += extra
    return {**dict(field), "degree": degree, "coefficients_dn": total.tolist()}


def _factor(rng: np.random.Generator, sigma: float, size=None):
    return np.exp(rng.normal(0.0, float(sigma), size))


def _light(light: dict, spread: Mapping, rng: np.random.Generator) -> dict:
    light = dict(light)
    light["azimuth_deg"] = float(
        light["azimuth_deg"] + rng.normal(0, spread.get("light_azimuth_deg", 0))
    )
    elevation = light["elevation_deg"] + rng.normal(0, spread.get("light_elevation_deg", 0))
    light["elevation_deg"] = float(np.clip(elevation, 1.0, 89.0))
    light["distance_mm"] = float(
        light["distance_mm"] * _factor(rng, spread.get("light_distance", 0))
    )
    light["gain_dn"] = float(light["gain_dn"] * _factor(rng, spread.get("light_gain", 0)))
    colour = np.asarray(light["color_rgb"], float) * _factor(rng, spread.get("light_colour", 0), 3)
    light["color_rgb"] = (colour / colour.max()).tolist()
    scatter = np.asarray(light["scatter_dn"], float) * _factor(rng, spread.get("light_scatter", 0))
    light["scatter_dn"] = scatter.tolist() if scatter.ndim else float(scatter)
    return light


def _optics(optics: dict, spread: Mapping, rng: np.random.Generator) -> dict:
    optics = copy.deepcopy(optics)
    ambient = np.asarray(optics.get("ambient_dn", [0, 0, 0]), float)
    optics["ambient_dn"] = np.clip(
        ambient + rng.normal(0, spread.get("ambient_dn", 0), 3), 0, None
    ).tolist()
    field = optics.get("background_field")
    if field:
        coefficients = np.asarray(field["coefficients_dn"], float)
        scale = 1 + rng.normal(0, spread.get("background_field", 0), coefficients.shape)
        field["coefficients_dn"] = (coefficients * scale).tolist()
    for spot in optics.get("hot_spots") or []:
        amplitude = np.asarray(spot["amplitude_dn"], float)
        spot["amplitude_dn"] = (amplitude * _factor(rng, spread.get("hot_spot", 0))).tolist()
    optics["blur_sigma_px"] = float(
        optics.get("blur_sigma_px", 0) * _factor(rng, spread.get("blur", 0))
    )
    noise = np.asarray(optics.get("noise_dn", [0, 0, 0]), float)
    optics["noise_dn"] = (noise * _factor(rng, spread.get("noise", 0))).tolist()
    nonlinearity = optics.get("nonlinearity", 0.0) + rng.normal(0, spread.get("nonlinearity", 0))
    optics["nonlinearity"] = float(np.clip(nonlinearity, 0.0, 2.0))
    return optics


def _gel(gel: dict, spread: Mapping, rng: np.random.Generator) -> dict:
    gel = dict(gel)
    gel["thickness_mm"] = float(gel["thickness_mm"] * _factor(rng, spread.get("gel_thickness", 0)))
    if "youngs_modulus_mpa" in gel:
        gel["youngs_modulus_mpa"] = float(
            gel["youngs_modulus_mpa"] * _factor(rng, spread.get("youngs_modulus", 0))
        )
    span = spread.get("skin_tension_range_n_per_mm")
    if span:
        low, high = (float(v) for v in span)
        if not 0 <= low <= high:
            raise ConfigError(
                f"unit_variation.skin_tension_range_n_per_mm: [{low}, {high}] must be 0 <= low <= high"
            )
        gel["skin_tension_n_per_mm"] = float(rng.uniform(low, high))
    elif gel.get("skin_tension_n_per_mm"):
        gel["skin_tension_n_per_mm"] = float(
            gel["skin_tension_n_per_mm"] * _factor(rng, spread.get("skin_tension", 0))
        )
    return gel
