"""How real units differ (threedcal.realism.unit_measure), against synthetic frames with known answers."""

import math

import numpy as np
import pytest

from threedcal.errors import ConfigError
from threedcal.realism import unit_measure as um
from threedcal.sim.background_field import field_terms


def _field(width, height, coefficients, degree=4):
    return np.einsum(
        "khw,ck->hwc", np.stack(field_terms(width, height, degree)).astype(float), coefficients
    )


@pytest.mark.parametrize("shape", [(41, 29), (320, 240), (17, 64)])
def test_a_smooth_field_is_recovered_exactly_with_or_without_a_mask(shape):
    height, width = shape
    coefficients = np.random.default_rng(1).normal(0, 20, (3, 15))
    image = 100 + _field(width, height, coefficients)
    np.testing.assert_allclose(um.smooth_field(image), image, atol=1e-6)
    keep = np.ones(shape, bool)
    keep[height // 4 : height // 2, width // 3 :] = False  # a contact, a marker row, ...
    np.testing.assert_allclose(um.smooth_field(image, keep), image, atol=1e-6)


def test_level_and_shape_of_a_ramp_and_the_difference_of_two_units_brightness_aside():
    height, width = 31, 21
    cols = np.arange(width, dtype=float)
    ramp = np.broadcast_to((cols - cols.mean())[None, :, None], (height, width, 3))
    a = 80 + np.array([1.0, 2.0, 0.0]) * ramp
    level, shape = um.field_level_and_shape(a)
    np.testing.assert_allclose(level, 80, atol=1e-9)
    rms = math.sqrt(((cols - cols.mean()) ** 2).mean())
    np.testing.assert_allclose(shape, [rms, 2 * rms, 0.0], atol=1e-6)
    # a unit 30 DN brighter whose red field is tilted the other way: only the shape counts
    b = 110 + np.array([-1.0, 2.0, 0.0]) * ramp
    np.testing.assert_allclose(um.field_difference_dn(a, b), [2 * rms, 0, 0], atol=1e-6)


@pytest.mark.parametrize("azimuth", [0.0, 37.0, 90.0, 180.0, 225.0, 359.0])
def test_the_brighter_side_is_the_direction_the_field_rises(azimuth):
    height, width = 45, 33  # odd, unequal sides: pixels, not normalised coordinates
    yy, xx = np.mgrid[:height, :width].astype(float)
    t = math.radians(azimuth)
    rise = math.cos(t) * xx + math.sin(t) * yy
    image = np.stack([50 + 0.8 * rise, 90 - 0.5 * rise, 70 + 0.3 * rise], axis=-1)
    keep = np.ones((height, width), bool)
    keep[10:20, 5:25] = False
    sides = um.brighter_side_deg(image, keep)
    expected = [azimuth, (azimuth + 180) % 360, azimuth]
    np.testing.assert_allclose(um.angle_difference_deg(sides, expected), 0, atol=1e-6)


def test_each_lights_direction_is_read_from_sphere_contacts():
    height, width, radius = 90, 120, 20.0
    blank = 60 + _field(width, height, np.random.default_rng(2).normal(0, 10, (3, 15)))
    yy, xx = np.mgrid[:height, :width].astype(float)
    lights = np.radians([322.0, 199.0, 73.0])  # one per channel
    frames, centres = [], [(40.3, 45.1), (75.0, 50.6)]
    for k, (cx, cy) in enumerate(centres):
        nx, ny = (xx - cx) / radius, (yy - cy) / radius
        r2 = nx**2 + ny**2
        nz = np.sqrt(np.clip(1 - r2, 0, 1))
        change = np.stack(
            [40 * (np.cos(a) * nx + np.sin(a) * ny) - 15 * nz for a in lights], axis=-1
        )
        drift = np.array([3.0, -2.0, 5.0 + k])  # the frame's uniform drift from its blank
        frames.append(blank + drift + np.where((r2 < 1)[..., None], change, 0.0))
    found = um.contact_light_deg(frames, blank, centres, radius)
    np.testing.assert_allclose(
        um.angle_difference_deg(found, np.degrees(lights) % 360), 0, atol=1e-6
    )
    # pixels marked invalid (markers) take no part: garbage there changes nothing
    spoiled = [f.copy() for f in frames]
    valid = [np.ones((height, width), bool) for _ in frames]
    for f, ok in zip(spoiled, valid, strict=True):
        f[40:44, 36:80] = 0.0
        ok[40:44, 36:80] = False
    again = um.contact_light_deg(spoiled, blank, centres, radius, valid=valid)
    np.testing.assert_allclose(um.angle_difference_deg(again, found), 0, atol=1e-6)
    with pytest.raises(ConfigError, match="one centre per contact frame"):
        um.contact_light_deg(frames, blank, centres[:1], radius)


def test_the_halo_is_where_a_known_radial_profile_falls_to_half_and_a_tenth():
    size, centre, ball = 301, (150.0, 150.0), 50.0
    yy, xx = np.mgrid[:size, :size].astype(float)
    r = np.hypot(xx - centre[0], yy - centre[1])
    # flat to 20 px, then falling linearly to 0 at 100 px: 50 % at 60 px, 10 % at 92 px
    magnitude = np.clip(1 - (r - 20) / 80, 0, 1) * 100
    blank = np.full((size, size, 3), 100.0)
    frame = blank.copy()
    frame[..., 0] += magnitude
    r50, r10 = um.halo_over_radius(frame, blank, centre, ball)
    assert r50 == pytest.approx(60 / ball, abs=0.5 / ball)
    assert r10 == pytest.approx(92 / ball, abs=0.5 / ball)


def test_a_spread_is_what_units_differ_by_over_root_two_on_the_line_and_the_circle():
    np.testing.assert_allclose(
        um.spread([[1.0, 5.0], [3.0, 1.0]]), [2 / math.sqrt(2), 4 / math.sqrt(2)]
    )
    np.testing.assert_allclose(um.spread([[350.0], [10.0]], angular=True), [20 / math.sqrt(2)])
    np.testing.assert_allclose(um.spread([[0.0], [3.0], [6.0]]), [3.0])
    np.testing.assert_allclose(
        um.angle_difference_deg([10, 190, 0], [350, 10, 180]), [20, 180, 180]
    )
    with pytest.raises(ConfigError, match="at least two units"):
        um.spread([[1.0, 2.0]])


def test_too_few_pixels_or_a_wrong_mask_is_refused():
    image = np.zeros((20, 20, 3))
    with pytest.raises(ConfigError, match="too few"):
        um.smooth_field(image, np.zeros((20, 20), bool))
    with pytest.raises(ConfigError, match="keep mask of shape"):
        um.smooth_field(image, np.ones((10, 20), bool))
    with pytest.raises(ConfigError, match="blanks of shapes"):
        um.field_difference_dn(image, np.zeros((20, 21, 3)))


def test_markers_and_their_rims_are_kept_out():
    height, width = 60, 80
    image = np.full((height, width, 3), 150.0)
    image += np.linspace(0, 40, width)[None, :, None]  # a bright side: no marker
    yy, xx = np.mgrid[:height, :width]
    distance = np.hypot((xx - 20) % 30 - 10, (yy - 15) % 30 - 10)  # to the nearest marker's centre
    image[distance <= 3] = 30.0
    keep = um.away_from_markers(image, grow_px=2)
    assert not keep[distance <= 4].any()  # the marker and its rim (the square grow reaches 5-6 px)
    assert keep[distance > 6].all()
