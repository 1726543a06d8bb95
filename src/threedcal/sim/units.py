"""Units of one sensor model that differ as manufactured units do: the profile's constants drawn
around their values by the spreads of its `unit_variation` block.

Two DIGITs or two GelSight Minis of one design do not image a press alike: their LEDs sit and
diffuse differently, their gels are poured thicker or softer, their cameras blur and noise
differently. A model trained on one unit is then a poor start for the next; one trained on many
draws of this variation is a start for any. `draw_unit(profile, seed)` is one such unit: the same
seed always gives the same unit. Where the camera sits (the seating in the printed base) and its
lens are drawn by the bench itself (threedcal.sim.bench), per seed, for every unit.
"""

from __future__ import annotations

import copy
from collections.abc import Mapping

import numpy as np

from threedcal.errors import ConfigError

# Unit seeds are drawn apart from the bench's other streams (noise, seating) of the same number.
_STREAM = 0x0417


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
    return unit


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
    if gel.get("skin_tension_n_per_mm"):
        gel["skin_tension_n_per_mm"] = float(
            gel["skin_tension_n_per_mm"] * _factor(rng, spread.get("skin_tension", 0))
        )
    return gel
