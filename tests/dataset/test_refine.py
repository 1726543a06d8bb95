"""Contact labels refined from the images (threedcal.dataset.refine), tested on simulated frames."""

import math

import numpy as np
import pandas as pd
import pytest

from threedcal.dataset.refine import refine_contacts, refine_labels, ring_profile, symmetric_centre
from threedcal.dataset.trainset import TrainingSet
from threedcal.errors import ConfigError
from threedcal.profiles import load_profile
from threedcal.sim.indenters import Sphere
from threedcal.sim.optics import GelSimulator

BALL_MM, PX_PER_MM, SIZE = 2.0, 12.0, (112, 96)  # (width, height): the Mini's landscape frame


@pytest.fixture(scope="module")
def rendered():
    """12 ball presses of known centre and depth, rendered by the GelSimulator (Mini optics)."""
    sim = GelSimulator(
        load_profile("sensor", "gelsight_mini"), 0, image_size=SIZE, px_per_mm=PX_PER_MM
    )
    rng = np.random.default_rng(4)
    centres = rng.uniform([46, 40], [SIZE[0] - 46, SIZE[1] - 40], (12, 2))
    depths = rng.uniform(0.5, 1.2, 12)
    frames = np.stack(
        [
            sim.render(Sphere(BALL_MM), tuple(c), 0.0, float(d), frame_index=i + 1)
            for i, (c, d) in enumerate(zip(centres, depths, strict=True))
        ]
    )
    contact = np.sqrt(2 * BALL_MM * depths - depths**2) * PX_PER_MM
    return frames, sim.blank(0), centres, depths, contact


def test_a_radially_symmetric_field_has_its_centre_found_to_a_fraction_of_a_pixel():
    rows, cols = np.mgrid[0:60, 0:70]
    field = np.exp(-((np.hypot(cols - 33.3, rows - 28.6) - 12) ** 2) / 20)
    cx, cy = symmetric_centre(field, 30.0, 31.0, 20.0)
    assert cx == pytest.approx(33.3, abs=0.15) and cy == pytest.approx(28.6, abs=0.15)
    mean, left = ring_profile(field, 33.3, 28.6, 20.0)
    assert left < 0.01 and np.argmax(mean) * 0.5 == pytest.approx(12, abs=0.5)


def test_simulated_presses_get_their_true_centre_and_radius_back_from_noisy_labels(rendered):
    frames, blank, centres, _, contact = rendered
    rng = np.random.default_rng(0)
    drawn_c = centres + rng.normal(0, 2.5, centres.shape)  # hand-drawn: a few px off
    drawn_r = contact + rng.normal(0, 2.5, contact.shape)
    found_c, found_r = refine_contacts(frames, blank, drawn_c, drawn_r)
    centre_error = np.hypot(*(found_c - centres).T)
    assert centre_error.max() < 0.5, centre_error
    # relative sizes from the images, the common level from the labels' mean (its error is shared)
    level = drawn_r.mean() - contact.mean()
    assert np.abs(found_r - level - contact).max() < 0.5
    assert np.std(found_r - contact) < 0.25 < np.std(drawn_r - contact) / 5


def test_refined_labels_move_depth_with_the_radius_and_keep_the_evaluation_ratio(rendered):
    frames, blank, centres, depths, contact = rendered
    n = len(depths)
    samples = pd.DataFrame(
        {
            "frame": range(n),
            "point": range(n),
            "center_x_px": centres[:, 0] + 2.0,
            "center_y_px": centres[:, 1] - 1.5,
            "depth_mm": depths,
            "eval_radius_px": 0.9 * contact,
            "split": ["train"] * n,
            "min_p": [80] * n,
        }
    )
    ts = TrainingSet(frames, blank.astype(np.float32), samples, PX_PER_MM, BALL_MM)
    refined = refine_labels(ts)
    np.testing.assert_allclose(refined.center_px, centres, atol=0.5)
    a = np.sqrt(2 * BALL_MM * refined.depth_mm - refined.depth_mm**2) * PX_PER_MM
    np.testing.assert_allclose(refined.eval_radius_px, 0.9 * a)
    np.testing.assert_allclose(a, contact, atol=0.5)
    assert "refined" in refined.meta["labels"]


def test_a_frame_without_a_ball_imprint_is_refused(rendered):
    frames, blank, centres, _, contact = rendered
    frames = frames.copy()
    frames[3] = np.asarray(blank, dtype=np.uint8)  # nothing pressed
    with pytest.raises(ConfigError, match=r"frame\(s\) \[3\]"):
        refine_contacts(frames, blank, centres, contact)
    with pytest.raises(ConfigError, match="at least 3"):
        refine_contacts(frames[:2], blank, centres[:2], contact[:2])
    assert math.isfinite(float(contact.mean()))
