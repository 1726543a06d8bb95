"""The optics fit (threedcal.realism.fit) and the out-of-sample realism split."""

import copy
import math

import cv2
import numpy as np
import pytest

from threedcal.errors import ConfigError
from threedcal.profiles import load_profile
from threedcal.realism.check import (
    BallLabel,
    halo_radii,
    image_groups,
    load_ball_dataset,
    locate_ball,
)
from threedcal.realism.fit import fit_optics
from threedcal.realism.folder import realism_report, split_halves
from threedcal.sim.indenters import Sphere
from threedcal.sim.optics import GelSimulator, background_field

W, H, PX_PER_MM, BALL_MM = 160, 200, 12.0, 2.35
CENTRES = [(60, 70), (100, 80), (70, 130), (105, 135), (80, 100), (95, 60), (60, 150), (110, 110)]
DEPTHS = [0.8, 1.0, 1.2, 0.9, 1.1, 0.7, 1.0, 1.3]


def truth_profile():
    """The Mini with other, known optics: pure LED colours, moved LEDs, new levels and noise; its
    normal-independent light an ambient and a smooth field (the fit's model: no LED scatter)."""
    p = copy.deepcopy(load_profile("sensor", "gelsight_mini"))
    for li, az, gain, col in zip(
        p["lights"],
        (260.0, 100.0, 200.0),
        (90.0, 70.0, 110.0),
        ([1, 0, 0], [0, 1, 0], [0, 0, 1]),
        strict=True,
    ):
        li.update(azimuth_deg=az, gain_dn=gain, color_rgb=col, elevation_deg=14.0, scatter_dn=0.0)
    p["optics"].update(
        nonlinearity=0.8,
        blur_sigma_px=0.8,
        noise_dn=[1.5, 0.8, 1.1],
        noise_correlation_px=0.7,
        ambient_dn=[10.0, 0.0, 30.0],
        frame_gain_jitter=0.0,
        background_field={"degree": 1, "coefficients_dn": [[0, 8, 0], [0, 0, -6], [0, 0, 0]]},
    )
    return p


def write_folder(root, profile, labelled=True, n=8, landscape=False):
    """A ball folder rendered by the simulator: background.png, frames, dataset.yaml, labels.csv.
    `landscape`: W and H (and the centres) exchanged, upright for a landscape profile, which the
    realism check reads as it is (a portrait folder would have to say which way it turns)."""
    root.mkdir(parents=True, exist_ok=True)
    size = (H, W) if landscape else (W, H)
    sim = GelSimulator(profile, 3, image_size=size, px_per_mm=PX_PER_MM)
    cv2.imwrite(str(root / "background.png"), sim.blank(0)[..., ::-1])
    rows = ["image,center_x_px,center_y_px,radius_px"]
    for i, (c, d) in enumerate(zip(CENTRES[:n], DEPTHS[:n], strict=True)):
        c = c[::-1] if landscape else c
        name = f"{i:04d}.png"
        cv2.imwrite(
            str(root / name), sim.render(Sphere(BALL_MM), c, 0, d, frame_index=i + 1)[..., ::-1]
        )
        a_px = math.sqrt(2 * BALL_MM * d - d * d) * PX_PER_MM
        rows.append(f"{name},{c[0]},{c[1]},{a_px:.3f}")
    (root / "dataset.yaml").write_text(f"px_per_mm: {PX_PER_MM}\nball_radius_mm: {BALL_MM}\n")
    if labelled:
        (root / "labels.csv").write_text("\n".join(rows) + "\n")
    return root


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    truth = truth_profile()
    return truth, load_ball_dataset(write_folder(tmp_path_factory.mktemp("fit") / "ball", truth))


def test_fit_recovers_the_optics_the_frames_were_rendered_with(rendered):
    truth, data = rendered
    start = load_profile("sensor", "gelsight_mini")  # other colours, places, levels, noise
    fit = fit_optics(
        start,
        data,
        data.labels,
        elevations_deg=(10.0, 14.0, 20.0),
        nonlinearities=(0.4, 0.8),
        blurs_px=(0.8, 2.0),
    )
    got = fit.profile
    # shading shape: the grid point the frames were rendered at
    assert [li["elevation_deg"] for li in got["lights"]] == [14.0] * 3
    assert got["optics"]["nonlinearity"] == 0.8 and got["optics"]["blur_sigma_px"] == 0.8
    for li, true in zip(got["lights"], truth["lights"], strict=True):
        assert li["azimuth_deg"] == pytest.approx(true["azimuth_deg"], abs=3.0)
        directional = li["gain_dn"] * np.asarray(li["color_rgb"])
        expected = true["gain_dn"] * np.asarray(true["color_rgb"], float)
        assert np.abs(directional - expected).max() < 0.06 * true["gain_dn"], (li, true)
    # the background the fitted optics render is the true one (its split into ambient, scatter and
    # smooth field is not identified by a background alone)
    size = dict(image_size=(W, H), px_per_mm=PX_PER_MM)
    diff = GelSimulator(got, 0, **size).background - GelSimulator(truth, 0, **size).background
    assert float(np.sqrt(np.mean(diff**2))) < 1.5
    assert got["optics"]["noise_dn"] == pytest.approx(truth["optics"]["noise_dn"], rel=0.12)
    assert got["optics"]["noise_correlation_px"] == pytest.approx(0.7, abs=0.15)


def label(x, y, name="x"):
    return BallLabel(name, (float(x), float(y)), 20.0)


def test_split_keeps_presses_together_and_never_puts_an_image_in_both_halves():
    # presses 0, 3 and 7 repeat one place; 5 and 6 another (within 4 px); the rest are alone
    places = [(10, 10), (50, 10), (90, 10), (11, 12), (10, 60), (60, 60), (63, 61), (13, 14)]
    labels = [label(x, y, f"{i:02d}.png") for i, (x, y) in enumerate(places)]
    assert image_groups(labels) == [[0, 3, 7], [1], [2], [4], [5, 6]]
    seen = set()
    for seed in range(20):
        fit, test = split_halves(labels, seed)
        a, b = {lb.image for lb in fit}, {lb.image for lb in test}
        assert not a & b and a | b == {lb.image for lb in labels}
        for group in ([0, 3, 7], [5, 6]):
            names = {labels[i].image for i in group}
            assert names <= a or names <= b
        assert abs(len(a) - len(b)) <= 3
        seen.add(frozenset(a))
    assert len(seen) > 3  # the seed decides
    assert split_halves(labels, 5) == split_halves(labels, 5)


def test_clear_errors_for_too_few_images_or_no_background(tmp_path):
    with pytest.raises(ConfigError, match="3 contact images.*at least 4"):
        split_halves([label(10 * i, 0) for i in range(3)], 0, where="somewhere")
    with pytest.raises(ConfigError, match="every image is one press"):
        split_halves([label(0, 0)] * 5, 0)
    root = write_folder(tmp_path / "nobg", truth_profile(), n=2)
    (root / "background.png").unlink()
    with pytest.raises(ConfigError, match="nobg: no background.png"):
        load_ball_dataset(root)


def test_halo_radii_of_a_sharp_disc_are_its_edge_blurred():
    bg = np.full((120, 140, 3), 100, np.uint8)
    img = bg.copy()
    yy, xx = np.mgrid[:120, :140]
    img[(xx - 70.0) ** 2 + (yy - 60.0) ** 2 <= 20.0**2] = 160
    r50, r10 = halo_radii(img, bg, (70.0, 60.0), 25.0)
    # the contact magnitude is blurred by sigma 2: half height at the edge, 10 % at +1.28 sigma
    assert r50 == pytest.approx(20.5, abs=0.6)
    assert r10 - r50 == pytest.approx(1.2816 * 2, abs=0.6)
    found = locate_ball(img, bg, 25.0, "disc")
    assert found.center_px == pytest.approx((70.0, 60.0), abs=0.1) and found.located
    assert found.radius_px == pytest.approx(20.0, abs=0.7)
    with pytest.raises(ConfigError, match="blank: no contact found"):
        locate_ball(bg, bg, 25.0, "blank")


def test_background_field_is_the_polynomial_it_names():
    field = background_field(5, 3, 1, [[1, 2, 0], [0, 0, 3], [0, 0, 0]])
    assert field[:, :, 0].tolist() == [[-1, 0, 1, 2, 3]] * 3  # 1 + 2u, u = -1 .. 1
    assert field[:, 0, 1].tolist() == [-3, 0, 3]  # 3v
    with pytest.raises(ConfigError, match="3 rows of 3 coefficients"):
        background_field(5, 3, 1, [[1, 2]] * 3)


def test_report_is_out_of_sample_and_says_what_unlabelled_frames_cannot_check(tmp_path):
    root = write_folder(
        tmp_path / "unlabelled", truth_profile(), labelled=False, n=5, landscape=True
    )
    text, _ = realism_report(root, "gelsight_mini", split_seed=1)
    assert "unlabelled" in text and "OUT OF SAMPLE" in text
    assert "not checked without labels: r2_R, r2_G, r2_B, halo_r50_px" in text
    fit_line = next(line for line in text.splitlines() if line.startswith("# fitted"))
    test_line = next(line for line in text.splitlines() if line.startswith("OUT OF SAMPLE"))
    fitted = {n for n in (f"{i:04d}.png" for i in range(5)) if n in fit_line}
    compared = {n for n in (f"{i:04d}.png" for i in range(5)) if n in test_line}
    assert fitted and compared and not fitted & compared and len(fitted | compared) == 5
    assert "r2_R " not in text.split("figure")[1].split("realism:")[0]


def test_digit_fots_profile_renders_the_real_digit_background(real_data):
    """The fitted DIGIT optics (profile digit_fots) reproduce the real background's colour field:
    per channel its low-passed render correlates with background.png's (the Mini's levels with the
    LEDs moved, the digit profile, do not)."""
    real = cv2.imread(str(real_data / "digit_frames_fots/background.png"))[..., ::-1]

    def correlation(name):
        sim = GelSimulator(load_profile("sensor", name), 0, px_per_mm=19.58)
        low = [cv2.GaussianBlur(im.astype(np.float32), (0, 0), 4) for im in (sim.blank(0), real)]
        return [np.corrcoef(low[0][..., c].ravel(), low[1][..., c].ravel())[0, 1] for c in range(3)]

    assert min(correlation("digit_fots")) > 0.8
    assert min(correlation("digit")) < 0.5
