import json
import re

import cv2
import numpy as np
import pandas as pd
import pytest
import yaml

from threedcal.dataset.importers import load_ball_folder, load_imported, load_py3dcal_folder
from threedcal.errors import ConfigError


def write_rgb(path, image):
    path.parent.mkdir(parents=True, exist_ok=True)
    assert cv2.imwrite(str(path), cv2.cvtColor(image, cv2.COLOR_RGB2BGR))


def images(n, shape=(32, 24), seed=0):
    rng = np.random.default_rng(seed)
    return [rng.integers(0, 256, (*shape, 3), dtype=np.uint8) for _ in range(n)]


def make_ball_folder(root, rows=None):
    frames = images(3)
    blank = images(1, seed=9)[0]
    for i, frame in enumerate(frames):
        write_rgb(root / f"{i:04d}.png", frame)
    write_rgb(root / "background.png", blank)
    rows = rows or [(f"{i:04d}.png", 10 + i, 12.5, 5 + i) for i in range(3)]
    pd.DataFrame(rows, columns=["image", "center_x_px", "center_y_px", "radius_px"]).to_csv(
        root / "labels.csv", index=False
    )
    (root / "dataset.yaml").write_text(yaml.safe_dump({"px_per_mm": 10.0, "ball_radius_mm": 2.0}))
    return frames, blank


def test_ball_folder_round_trip(tmp_path):
    frames, blank = make_ball_folder(tmp_path)
    data = load_ball_folder(tmp_path)
    np.testing.assert_array_equal(data.frames, np.stack(frames))  # RGB kept, lossless PNG
    np.testing.assert_array_equal(data.blank, blank)
    np.testing.assert_allclose(data.center_px, [[10, 12.5], [11, 12.5], [12, 12.5]])
    # Contact radius r px at 10 px/mm on a 2 mm ball → depth R - sqrt(R² - (r/10)²).
    np.testing.assert_allclose(data.depth_mm, 2 - np.sqrt(4 - (np.array([5, 6, 7]) / 10) ** 2))
    np.testing.assert_allclose(data.eval_radius_px, 0.9 * np.array([5, 6, 7]))


def test_ball_folder_eval_radius_is_capped_below_the_ball(tmp_path):
    make_ball_folder(tmp_path, rows=[("0000.png", 10, 10, 19.9)])
    data = load_ball_folder(tmp_path)
    assert data.eval_radius_px[0] == pytest.approx(0.9 * 0.98 * 20)


def test_bad_label_row_is_named(tmp_path):
    make_ball_folder(tmp_path, rows=[("0000.png", 10, 10, 5), ("0001.png", "x", 10, 5)])
    with pytest.raises(
        ConfigError, match=r"labels.csv, row 3: center_x_px='x' must be a finite number"
    ):
        load_ball_folder(tmp_path)


def test_missing_image_and_missing_column_are_named(tmp_path):
    make_ball_folder(tmp_path)
    (tmp_path / "0001.png").unlink()
    with pytest.raises(ConfigError, match="0001.png: missing or not a readable image"):
        load_ball_folder(tmp_path)
    pd.DataFrame({"image": ["0000.png"]}).to_csv(tmp_path / "labels.csv", index=False)
    with pytest.raises(ConfigError, match="missing column"):
        load_ball_folder(tmp_path)


def test_radius_at_least_the_ball_is_refused(tmp_path):
    make_ball_folder(tmp_path, rows=[("0000.png", 10, 10, 20)])
    with pytest.raises(ConfigError, match="row 2: radius_px=20"):
        load_ball_folder(tmp_path)


def make_py3dcal_folder(root):
    frames = images(4, seed=2)
    write_rgb(root / "blank_images/blank.png", images(1, seed=5)[0])
    rows, names = [], []
    coords = [(1.0, 2.0), (1.0, 2.0), (1.5, 2.0), (1.5, 2.5)]
    for i, ((x, y), frame) in enumerate(zip(coords, frames, strict=True)):
        name = f"{i}_X{x}Y{y}Z1.0.png"
        write_rgb(root / "probe_images" / name, frame)
        rows.append((name, x, y, 1.0, 10 + x * 20, 20 - y * 5))
        names.append(name)
    rows.insert(2, ("---", 9.0, 9.0, 1.0, 0, 0))  # a failed capture, as py3DCal writes it
    columns = ["img_name", "x_mm", "y_mm", "penetration_depth_mm", "x_px", "y_px"]
    (root / "annotations").mkdir()
    pd.DataFrame(rows, columns=columns).to_csv(root / "annotations/annotations.csv", index=False)
    (root / "annotations/metadata.json").write_text(
        json.dumps({"px_per_mm": 20.0, "probe_radius_mm": 2.0})
    )
    return frames, names


def test_py3dcal_round_trip_groups_frames_by_coordinate(tmp_path):
    frames, names = make_py3dcal_folder(tmp_path)
    data = load_imported("py3dcal", tmp_path)
    assert data.names == names
    np.testing.assert_array_equal(data.frames, np.stack(frames))
    assert data.point.tolist() == [0, 0, 1, 2]
    np.testing.assert_allclose(data.center_px[:, 0], [30, 30, 40, 40])
    assert data.px_per_mm == 20 and data.sphere_radius_mm == 2


def test_py3dcal_missing_metadata_says_to_annotate(tmp_path):
    make_py3dcal_folder(tmp_path)
    (tmp_path / "annotations/metadata.json").unlink()
    with pytest.raises(ConfigError, match="metadata.json: missing"):
        load_py3dcal_folder(tmp_path)


def test_unknown_format_lists_allowed():
    with pytest.raises(ConfigError, match="allowed: ball_folder, py3dcal"):
        load_imported("zip", "x")


def test_vendored_real_dataset_loads(real_data):
    data = load_ball_folder(real_data / "gelsight_ball_fots")
    assert data.frames.shape == (42, 320, 240, 3)
    assert data.px_per_mm == pytest.approx(19.58) and data.sphere_radius_mm == pytest.approx(2.35)
    assert np.all((data.depth_mm > 0) & (data.depth_mm < 2.35))


# ---- issue 22: every bad import is named with its file and row --------------------------------


@pytest.mark.parametrize(
    "row, message",
    [
        (
            ("0000.png", 24, 10, 5),
            "row 2: contact centre (center_x_px=24, center_y_px=10) px lies outside the 24 x 32 px image",
        ),
        (
            ("0000.png", 10, -1, 5),
            "row 2: contact centre (center_x_px=10, center_y_px=-1) px lies outside",
        ),
    ],
)
def test_ball_centres_outside_the_image_are_refused(tmp_path, row, message):
    make_ball_folder(tmp_path, rows=[row])
    with pytest.raises(ConfigError, match=re.escape(message)):
        load_ball_folder(tmp_path)


def test_ball_duplicate_rows_are_refused(tmp_path):
    make_ball_folder(
        tmp_path, rows=[("0000.png", 10, 10, 5), ("0001.png", 10, 10, 5), ("0000.png", 11, 10, 5)]
    )
    with pytest.raises(
        ConfigError, match=r"labels.csv, row 4: image '0000.png' is listed again \(first on row 2\)"
    ):
        load_ball_folder(tmp_path)


@pytest.mark.parametrize("name", ["../0000.png", "/etc/passwd", "sub/../../x.png"])
def test_ball_image_names_must_stay_inside_the_folder(tmp_path, name):
    make_ball_folder(tmp_path / "set", rows=[(name, 10, 10, 5)])
    with pytest.raises(
        ConfigError, match=r"labels.csv, row 2: image name .* must be a relative file name inside"
    ):
        load_ball_folder(tmp_path / "set")


@pytest.mark.parametrize(
    "image, message",
    [
        (np.full((32, 24), 128, np.uint8), "a grey image"),
        (np.full((32, 24, 3), 40000, np.uint16), "a 16-bit image"),
        (
            np.dstack([np.full((32, 24, 3), 9, np.uint8), np.full((32, 24), 100, np.uint8)]),
            "has transparent pixels",
        ),
    ],
    ids=["grey", "16-bit", "alpha"],
)
def test_ball_images_must_be_8_bit_rgb(tmp_path, image, message):
    make_ball_folder(tmp_path)
    assert cv2.imwrite(str(tmp_path / "0001.png"), image)
    with pytest.raises(ConfigError, match=f"0001.png: {message}"):
        load_ball_folder(tmp_path)


def test_opaque_rgba_images_are_read_as_rgb(tmp_path):
    frames, _ = make_ball_folder(tmp_path)
    bgra = cv2.cvtColor(frames[1], cv2.COLOR_RGB2BGRA)
    assert cv2.imwrite(str(tmp_path / "0001.png"), bgra)
    np.testing.assert_array_equal(load_ball_folder(tmp_path).frames[1], frames[1])


@pytest.mark.parametrize("content", ["[1, 2]", '"text"', "null"])
def test_py3dcal_metadata_must_be_an_object(tmp_path, content):
    """Repro: a metadata.json holding a list gave an AttributeError."""
    make_py3dcal_folder(tmp_path)
    (tmp_path / "annotations/metadata.json").write_text(content)
    with pytest.raises(ConfigError, match="metadata.json: must be a JSON object"):
        load_py3dcal_folder(tmp_path)


def test_py3dcal_duplicate_and_escaping_rows_are_named(tmp_path):
    make_py3dcal_folder(tmp_path)
    table = tmp_path / "annotations/annotations.csv"
    rows = pd.read_csv(table)
    rows.loc[len(rows)] = rows.iloc[0]
    rows.to_csv(table, index=False)
    with pytest.raises(
        ConfigError, match=r"annotations.csv, row 7: image .* is listed again \(first on row 2\)"
    ):
        load_py3dcal_folder(tmp_path)
    rows = rows.iloc[:-1].copy()
    rows.loc[1, "img_name"] = "../../blank_images/blank.png"
    rows.to_csv(table, index=False)
    with pytest.raises(
        ConfigError, match=r"annotations.csv, row 3: image name '../../blank_images"
    ):
        load_py3dcal_folder(tmp_path)


def test_non_numbers_in_messages_are_plain(tmp_path):
    make_ball_folder(tmp_path, rows=[("0000.png", float("nan"), 10, 5)])
    with pytest.raises(ConfigError) as exc:
        load_ball_folder(tmp_path)
    assert "center_x_px=nan must be a finite number" in str(exc.value)
    assert "np.float64" not in str(exc.value)


@pytest.mark.parametrize("value", [True, 0, -2.0, float("nan"), "10"])
def test_a_scale_that_is_not_a_positive_number_names_the_file_and_key(tmp_path, value):
    # `true` counts as 1 in Python: it passed as 1 px/mm, and the error that followed blamed the
    # labels' radii instead of the scale.
    make_ball_folder(tmp_path / "ball")
    meta = {"px_per_mm": value, "ball_radius_mm": 2.0}
    (tmp_path / "ball/dataset.yaml").write_text(yaml.safe_dump(meta))
    with pytest.raises(ConfigError, match=r"dataset.yaml: px_per_mm must be a positive number"):
        load_ball_folder(tmp_path / "ball")
    make_py3dcal_folder(tmp_path / "p3")
    meta = {"px_per_mm": 20.0, "probe_radius_mm": value}
    (tmp_path / "p3/annotations/metadata.json").write_text(json.dumps(meta))
    with pytest.raises(ConfigError, match=r"metadata.json: probe_radius_mm must be a positive"):
        load_imported("py3dcal", tmp_path / "p3")


def test_a_labels_key_that_is_not_a_file_name_is_named(tmp_path):
    # was: "ball/['a', 'b']: missing (table)", a path made of the list's text
    make_ball_folder(tmp_path)
    meta = {"px_per_mm": 10.0, "ball_radius_mm": 2.0, "labels": ["a.csv", "b.csv"]}
    (tmp_path / "dataset.yaml").write_text(yaml.safe_dump(meta))
    with pytest.raises(ConfigError, match=r"dataset.yaml: labels must be the labels table's file"):
        load_ball_folder(tmp_path)
    meta["labels"] = "../labels.csv"
    (tmp_path / "dataset.yaml").write_text(yaml.safe_dump(meta))
    with pytest.raises(
        ConfigError, match=r"labels: file name '../labels.csv' must be a relative file name"
    ):
        load_ball_folder(tmp_path)
