"""The bisecting first-contact search against exact answers: a synthetic contact whose signal grows
as α (c + δ)^p from a known onset, and the searches that miss it."""

import numpy as np
import pytest

from threedcal.dataset.touch import (
    TouchBisection,
    bisection_result,
    planned_touch_search,
)
from threedcal.errors import RegistrationError

SHAPE = (120, 160)
LOW, HIGH = -0.2, 0.3


def blank() -> np.ndarray:
    """A noise-free blank (every blank frame alike: no noise, so any change is contact): a bright
    disc about the press on a flat field that holds most pixels, so that the exposure gain and
    offset the search takes out (medians over the frame) stay exactly 1 and 0 under a press."""
    y, x = np.mgrid[0 : SHAPE[0], 0 : SHAPE[1]].astype(np.float32)
    base = np.where((x - 70) ** 2 + (y - 55) ** 2 < 35**2, 180.0, 100.0)
    return np.stack([base, base * 0.9 + 10, base * 0.8 + 20], axis=-1).astype(np.float32)


BLANKS = np.stack([blank()] * 4)


def pressed(c: float, delta: float, exponent: float, centre=(70.0, 55.0)) -> np.ndarray:
    """The frame at commanded depth c: a blob of colour change α (c + δ)^p, none above the gel."""
    y, x = np.mgrid[0 : SHAPE[0], 0 : SHAPE[1]].astype(np.float32)
    blob = np.exp(-((x - centre[0]) ** 2 + (y - centre[1]) ** 2) / (2 * 6.0**2))
    strength = 40.0 * max(c + delta, 0.0) ** exponent
    change = strength * blob[..., None] * np.array([1.0, -0.6, 0.4], np.float32)
    return blank() + change.astype(np.float32)


def search(delta: float, exponent: float = 1.5, presses: int = 8, **kwargs) -> TouchBisection:
    bisection = TouchBisection(BLANKS, LOW, HIGH, presses, px_per_mm=20.0, reach_mm=1.0, **kwargs)
    while (depth := bisection.next_depth()) is not None:
        bisection.observe(depth, pressed(depth, delta, exponent))
    return bisection


@pytest.mark.parametrize("exponent", [1.0, 1.5, 2.0])
@pytest.mark.parametrize("delta", [-0.137, -0.0412, 0.0, 0.0583, 0.19])
def test_the_search_finds_the_onset_exactly_in_eight_presses(delta, exponent):
    """The deepest press, four halvings of [-0.2, 0.3] mm, three presses past the bracket: the
    halvings bracket -δ to within 0.5 / 2^4 mm, and the growth fitted past it meets zero at -δ."""
    bisection = search(delta, exponent)
    depths = [p.depth_mm for p in bisection.pressed]
    assert len(depths) == 8 and depths[0] == HIGH
    assert all(LOW <= d <= HIGH for d in depths)
    low, high = bisection.bracket  # what the halvings left
    assert high - low == pytest.approx((HIGH - LOW) / 2**4)
    assert low <= -delta <= high
    # a press has contact exactly where it lies below the gel
    assert [p.contact for p in bisection.pressed] == [d + delta > 0 for d in depths]
    result = bisection.result()
    assert result.exponent == pytest.approx(exponent, abs=1e-9)
    assert result.offset_mm == pytest.approx(delta, abs=1e-5)


def test_the_halvings_follow_the_contact_test():
    """Each halving presses the middle of the bracket the last one left."""
    bisection = search(0.0583)
    depths = [p.depth_mm for p in bisection.pressed]
    low, high = LOW, HIGH
    for depth, press in zip(depths[1:5], bisection.pressed[1:5], strict=True):
        assert depth == pytest.approx((low + high) / 2)
        low, high = (low, depth) if press.contact else (depth, high)
    # the rest spread over the fit's span past the bracket's contact end
    assert np.diff(depths[5:]) == pytest.approx([0.04, 0.04])
    assert depths[5] == pytest.approx(high + 0.04)


def test_a_plans_search_adds_the_domes_sag_and_takes_it_off_again():
    """Two places (their own onsets, the sag 0.03 mm at one): each row is asked of its place, the
    commanded depth carries the sag, and the median over places is δ."""
    rows = np.array([[5.0, 5.0]] * 8 + [[6.0, 5.0]] * 8)
    sag = np.array([0.0] * 8 + [0.03] * 8)
    plan = planned_touch_search(rows, HIGH + sag, LOW, HIGH, px_per_mm=20.0, reach_mm=1.0)
    plan.begin(BLANKS)
    for k in range(16):
        depth = plan.depth(k)
        assert LOW + sag[k] <= depth <= HIGH + sag[k] + 1e-12
        plan.observe(k, depth, pressed(depth - sag[k], 0.071, 1.5)[None])
    result = plan.result()
    assert result.offset_mm == pytest.approx(0.071, abs=1e-5)
    np.testing.assert_allclose(result.place_offsets_mm, 0.071, atol=1e-5)
    with pytest.raises(RegistrationError, match="made all its presses"):
        plan.depth(0)


@pytest.mark.parametrize(
    "delta, message",
    [
        (0.25, "contact at every press.*touch_uncertainty_mm"),  # the gel above the window
        (-0.35, "no contact even at the deepest press.*beyond_mm"),  # below it
    ],
)
def test_a_search_that_misses_the_gel_says_which_setting_to_change(delta, message):
    with pytest.raises(RegistrationError, match=message):
        search(delta).result()


def test_too_few_presses_or_an_empty_window_are_refused_before_a_press():
    with pytest.raises(RegistrationError, match=">= 4 presses"):
        TouchBisection(BLANKS, LOW, HIGH, 3, px_per_mm=20.0, reach_mm=1.0)
    with pytest.raises(RegistrationError, match="rise from low to high"):
        TouchBisection(BLANKS, HIGH, LOW, 8, px_per_mm=20.0, reach_mm=1.0)
    with pytest.raises(RegistrationError, match=">= 3 RGB blank frames"):
        TouchBisection(BLANKS[:2], LOW, HIGH, 8, px_per_mm=20.0, reach_mm=1.0)
    unfinished = TouchBisection(BLANKS, LOW, HIGH, 8, px_per_mm=20.0, reach_mm=1.0)
    with pytest.raises(RegistrationError, match="0 of its 8 presses"):
        bisection_result([unfinished])


def test_noise_and_drift_leave_the_onset_within_a_hundredth_of_a_millimetre():
    """Blank frames with 1 DN of noise; presses 1 % brighter (an exposure drift, taken out) and
    with a faint broad shading no contact makes (a LED warming up: a signal every press carries,
    below the contact level): the presses without contact measure it, the fit takes it off, and
    δ comes out within 0.01 mm."""
    rng = np.random.default_rng(5)
    blanks = np.stack([blank() + rng.normal(0, 1.0, blank().shape) for _ in range(10)])
    y, x = np.mgrid[0 : SHAPE[0], 0 : SHAPE[1]].astype(np.float32)
    warm = 0.15 * np.exp(-((x - 75) ** 2 + (y - 50) ** 2) / (2 * 30.0**2))[..., None]
    bisection = TouchBisection(blanks.astype(np.float32), LOW, HIGH, 8, 20.0, 1.0)
    delta = 0.0417
    while (depth := bisection.next_depth()) is not None:
        frame = 1.01 * (pressed(depth, delta, 1.5) + warm) + rng.normal(0, 0.5, blank().shape)
        bisection.observe(depth, frame.astype(np.float32))
    without = [p.signal for p in bisection.pressed if not p.contact]
    assert without and 0.2 * bisection.level < np.mean(without) < bisection.level
    assert bisection.result().offset_mm == pytest.approx(delta, abs=0.01)


def test_an_onset_near_the_bottom_of_the_window_keeps_the_fit_inside_it():
    """Past a bracket that ends near the deepest press, the presses to fit crowd into what is left
    of the window rather than press deeper than the plan allows."""
    bisection = search(-0.2)
    assert max(p.depth_mm for p in bisection.pressed) == HIGH
    assert len({p.depth_mm for p in bisection.pressed}) == 8
    assert bisection.result().offset_mm == pytest.approx(-0.2, abs=1e-5)
