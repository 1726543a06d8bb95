"""The quarter turn between portrait and landscape frames (threedcal.orientation), and the readers
that take a folder stored on its side into the sensor profile's frame."""

import numpy as np
import pytest

from threedcal.dataset.importers import load_ball_folder, load_imported
from threedcal.orientation import needs_turn, orientation_of, turn_image, turn_points
from threedcal.realism.check import load_ball_dataset


def test_a_point_lands_where_the_turned_image_has_its_pixel():
    height, width = 5, 7
    image = np.zeros((height, width), int)
    points = [(0, 0), (6, 0), (0, 4), (6, 4), (2, 3)]
    for k, (x, y) in enumerate(points, start=1):
        image[y, x] = k
    turned = turn_image(image)
    assert turned.shape == (width, height) and turned.flags.c_contiguous
    for k, (x, y) in enumerate(turn_points(points, width), start=1):
        assert turned[int(y), int(x)] == k
    # counter-clockwise: the top row becomes the left column, the left column the bottom row
    np.testing.assert_array_equal(turned[:, 0], image[0, ::-1])
    np.testing.assert_array_equal(turned[-1, :], image[:, 0])
    # sub-pixel points follow the same map; a batch of frames turns in its own axes
    np.testing.assert_allclose(turn_points([(2.25, 3.5)], width), [[3.5, 6 - 2.25]])
    frames = np.stack([image, 2 * image])
    np.testing.assert_array_equal(turn_image(frames, axes=(1, 2))[1], 2 * turned)


def test_only_a_frame_on_its_side_against_the_profile_is_turned():
    assert orientation_of(320, 240) == "portrait" and orientation_of(240, 320) == "landscape"
    assert orientation_of(100, 100) is None
    assert needs_turn(320, 240, "landscape") and needs_turn(240, 320, "portrait")
    assert not needs_turn(320, 240, "portrait") and not needs_turn(240, 320, "landscape")
    assert not needs_turn(100, 100, "landscape")  # a square frame has no side
    assert not needs_turn(320, 240, None)  # no orientation stated: as stored
    with pytest.raises(ValueError, match="orientation must be one of"):
        needs_turn(320, 240, "upright")


def test_the_portrait_mini_folder_is_read_turned_with_its_labels(real_data):
    folder = real_data / "gelsight_ball_fots"
    stored = load_ball_folder(folder)
    turned = load_imported("ball_folder", folder, "landscape")
    assert stored.frames.shape[1:3] == (320, 240) and turned.frames.shape[1:3] == (240, 320)
    np.testing.assert_array_equal(turned.frames[3], np.rot90(stored.frames[3]))
    np.testing.assert_array_equal(turned.blank, np.rot90(stored.blank))
    np.testing.assert_allclose(turned.center_px, turn_points(stored.center_px, 240))
    np.testing.assert_array_equal(turned.depth_mm, stored.depth_mm)
    assert turned.metadata["read_turned_quarter"] is True
    # as the profile stores it already: untouched
    same = load_imported("ball_folder", folder, "portrait")
    np.testing.assert_array_equal(same.frames, stored.frames)

    # the realism check's reader agrees, image for image and label for label
    data = load_ball_dataset(folder, "landscape")
    assert data.turned and (data.width_px, data.height_px) == (320, 240)
    np.testing.assert_array_equal(data.read(data.labels[3].image), turned.frames[3])
    np.testing.assert_array_equal(data.read("background.png"), turned.blank)
    np.testing.assert_allclose([lb.center_px for lb in data.labels], turned.center_px)
    assert not load_ball_dataset(folder).turned
