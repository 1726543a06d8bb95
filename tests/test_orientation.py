"""The quarter turn between portrait and landscape frames (threedcal.orientation), and the readers
that take a folder stored on its side into the sensor profile's frame."""

import shutil

import numpy as np
import pytest

from threedcal.dataset.importers import load_ball_folder, load_imported
from threedcal.errors import ConfigError
from threedcal.orientation import (
    folder_turn,
    needs_turn,
    orientation_of,
    turn_image,
    turn_points,
)
from threedcal.realism.check import load_ball_dataset


@pytest.mark.parametrize("turn", ["counterclockwise", "clockwise"])
def test_a_point_lands_where_the_turned_image_has_its_pixel(turn):
    height, width = 5, 7
    image = np.zeros((height, width), int)
    points = [(0, 0), (6, 0), (0, 4), (6, 4), (2, 3)]
    for k, (x, y) in enumerate(points, start=1):
        image[y, x] = k
    turned = turn_image(image, turn=turn)
    assert turned.shape == (width, height) and turned.flags.c_contiguous
    for k, (x, y) in enumerate(turn_points(points, width, height, turn), start=1):
        assert turned[int(y), int(x)] == k
    frames = np.stack([image, 2 * image])
    np.testing.assert_array_equal(turn_image(frames, axes=(1, 2), turn=turn)[1], 2 * turned)
    # the two turns undo each other
    other = "clockwise" if turn == "counterclockwise" else "counterclockwise"
    np.testing.assert_array_equal(turn_image(turned, turn=other), image)
    back = turn_points(turn_points(points, width, height, turn), height, width, other)
    np.testing.assert_allclose(back, points)


def test_counterclockwise_takes_the_top_row_to_the_left_column():
    image = np.arange(35).reshape(5, 7)
    turned = turn_image(image)
    np.testing.assert_array_equal(turned[:, 0], image[0, ::-1])
    np.testing.assert_array_equal(turned[-1, :], image[:, 0])
    # sub-pixel points follow the same maps
    np.testing.assert_allclose(turn_points([(2.25, 3.5)], 7, 5), [[3.5, 6 - 2.25]])
    np.testing.assert_allclose(turn_points([(2.25, 3.5)], 7, 5, "clockwise"), [[4 - 3.5, 2.25]])


def test_only_a_frame_on_its_side_against_the_profile_is_turned_and_it_must_say_which_way():
    assert orientation_of(320, 240) == "portrait" and orientation_of(240, 320) == "landscape"
    assert orientation_of(100, 100) is None
    assert needs_turn(320, 240, "landscape") and needs_turn(240, 320, "portrait")
    assert not needs_turn(320, 240, "portrait") and not needs_turn(240, 320, "landscape")
    assert not needs_turn(100, 100, "landscape")  # a square frame has no side
    assert not needs_turn(320, 240, None)  # no orientation stated: as stored
    with pytest.raises(ValueError, match="orientation must be one of"):
        needs_turn(320, 240, "upright")
    assert folder_turn(320, 240, "landscape", "clockwise", "f") == "clockwise"
    assert folder_turn(320, 240, "portrait", None, "f") is None  # upright already: nothing asked
    with pytest.raises(ConfigError, match=r"my/dataset.yaml: .*turn_to_sensor: counterclockwise"):
        folder_turn(320, 240, "landscape", None, "my/dataset.yaml")
    with pytest.raises(ConfigError, match="got 'left'"):
        folder_turn(320, 240, "landscape", "left", "my/dataset.yaml")


def test_the_portrait_mini_folder_is_read_turned_with_its_labels(real_data):
    folder = real_data / "gelsight_ball_fots"
    stored = load_ball_folder(folder)
    turned = load_imported("ball_folder", folder, "landscape")
    assert stored.frames.shape[1:3] == (320, 240) and turned.frames.shape[1:3] == (240, 320)
    np.testing.assert_array_equal(turned.frames[3], np.rot90(stored.frames[3]))
    np.testing.assert_array_equal(turned.blank, np.rot90(stored.blank))
    np.testing.assert_allclose(turned.center_px, turn_points(stored.center_px, 240, 320))
    np.testing.assert_array_equal(turned.depth_mm, stored.depth_mm)
    assert turned.metadata["read_turned"] == "counterclockwise"
    # as the profile stores it already: untouched
    same = load_imported("ball_folder", folder, "portrait")
    np.testing.assert_array_equal(same.frames, stored.frames)

    # the realism check's reader agrees, image for image and label for label
    data = load_ball_dataset(folder, "landscape")
    assert data.turn == "counterclockwise" and (data.width_px, data.height_px) == (320, 240)
    np.testing.assert_array_equal(data.read(data.labels[3].image), turned.frames[3])
    np.testing.assert_array_equal(data.read("background.png"), turned.blank)
    np.testing.assert_allclose([lb.center_px for lb in data.labels], turned.center_px)
    assert not load_ball_dataset(folder).turned


def test_a_folder_on_its_side_that_does_not_say_which_way_is_refused_naming_its_file(
    real_data, tmp_path
):
    folder = tmp_path / "mini"
    shutil.copytree(real_data / "gelsight_ball_fots", folder)
    meta = folder / "dataset.yaml"
    meta.write_text(
        "".join(line for line in meta.read_text().splitlines(True) if "turn_to_sensor" not in line)
    )
    with pytest.raises(ConfigError, match=rf"{folder}/dataset.yaml: .*turn_to_sensor"):
        load_imported("ball_folder", folder, "landscape")
    with pytest.raises(ConfigError, match=rf"{folder}/dataset.yaml: .*turn_to_sensor"):
        load_ball_dataset(folder, "landscape")
    load_imported("ball_folder", folder, "portrait")  # as its sensor stores it: nothing to say
