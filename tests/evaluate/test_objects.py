"""Test objects: CAD meshes, STL files and ground-truth depth against analytic answers."""

from __future__ import annotations

import numpy as np
import pytest

from threedcal.errors import ConfigError
from threedcal.evaluate.groundtruth import (
    PenetrationError,
    depth_map,
    pose_vertices,
    surface_height,
)
from threedcal.evaluate.mesh import Mesh, height_field_solid, read_mesh, revolve, write_stl
from threedcal.evaluate.objects import (
    OBJECT_NAMES,
    PawnParams,
    load_object,
    make_object,
    pawn_profile,
)

PX_PER_MM = 19.5


def sphere(radius: float, sections: int = 256, rings: int = 128) -> Mesh:
    t = np.linspace(0, np.pi, rings + 1)
    profile = np.column_stack([-radius * np.cos(t), radius * np.sin(t)])
    profile[0, 1] = profile[-1, 1] = 0.0
    return revolve(profile, sections, name="sphere")


def sphere_cap_depth(shape, center, radius, indentation):
    rows, cols = np.indices(shape, dtype=float)
    rho2 = ((cols - center[0]) ** 2 + (rows - center[1]) ** 2) / PX_PER_MM**2
    height = radius - np.sqrt(np.clip(radius**2 - rho2, 0, None))
    return np.where(rho2 < radius**2, np.maximum(indentation - height, 0.0), 0.0)


@pytest.fixture(scope="module")
def objects():
    return {name: make_object(name) for name in OBJECT_NAMES}


def test_builtin_objects_are_closed_and_fit_in_10_mm(objects):
    r = 2.0
    expected = {
        "pill": np.pi * r**2 * (10 - 2 * r) + 4 / 3 * np.pi * r**3,
        "hemispheres": 10 * 10 * 1.0 + 2 / 3 * np.pi * (2.5**3 + 2**3 + 1.5**3 + 1**3),
    }
    for name, mesh in objects.items():
        assert mesh.is_watertight(), name
        lo, hi = mesh.bounds
        assert np.all(hi[:2] - lo[:2] <= 10 + 1e-9), name
        np.testing.assert_allclose((lo[:2] + hi[:2]) / 2, 0, atol=1e-9)
        assert lo[2] == pytest.approx(0, abs=1e-12)
        assert mesh.volume > 0
        if name in expected:  # inscribed facets: slightly less than the true solid
            assert expected[name] * 0.995 < mesh.volume <= expected[name] * (1 + 1e-9), name
    assert objects["pill"].extent == pytest.approx([10, 4, 4], abs=1e-6)
    assert objects["pawn"].extent[0] == pytest.approx(10)


def test_pawn_profile_has_vertical_walls_and_a_narrow_neck():
    p = PawnParams()
    prof = pawn_profile(p)
    flat = np.diff(prof[:, 0]) == 0  # equal z: a flat face, i.e. a vertical wall lying down
    assert flat.sum() >= 3
    assert prof[:, 1].max() == p.base_radius_mm
    with pytest.raises(ConfigError, match="neck"):
        make_object("pawn", neck_radius_mm=2.5)


def test_stl_roundtrip_binary_and_ascii(tmp_path, objects):
    path = write_stl(objects["pawn"], tmp_path / "pawn.stl")
    back = read_mesh(path)
    assert back.is_watertight()
    assert len(back.faces) == len(objects["pawn"].faces)
    assert back.volume == pytest.approx(objects["pawn"].volume, rel=1e-5)
    # an ASCII tetrahedron, wound inside out, away from the origin
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float) + [5, 5, 5]
    faces = [[0, 1, 2], [0, 3, 1], [0, 2, 3], [1, 3, 2]]  # inward normals
    lines = ["solid tet"]
    for f in faces:
        lines += ["facet normal 0 0 0", "outer loop"]
        lines += [f"vertex {a} {b} {c}" for a, b, c in v[f]]
        lines += ["endloop", "endfacet"]
    ascii_path = tmp_path / "tet.stl"
    ascii_path.write_text("\n".join(lines + ["endsolid tet"]))
    tet = load_object(str(ascii_path))
    assert tet.volume == pytest.approx(1 / 6)
    assert tet.bounds[0, 2] == 0 and tet.bounds[0, 0] == -0.5


def test_load_object_errors(tmp_path):
    with pytest.raises(ConfigError, match="hemispheres, pill, pawn"):
        load_object("rook")
    with pytest.raises(ConfigError, match="does not exist"):
        load_object(str(tmp_path / "missing.stl"))
    open_mesh = Mesh(np.eye(3), [[0, 1, 2]], "sheet")
    write_stl(open_mesh, tmp_path / "sheet.stl")
    with pytest.raises(ConfigError, match="watertight"):
        load_object(str(tmp_path / "sheet.stl"))
    (tmp_path / "junk.stl").write_bytes(b"\x00\xff" * 50)
    with pytest.raises(ConfigError, match="STL"):
        load_object(str(tmp_path / "junk.stl"))
    # a NaN corner (a broken export) would rasterise to nothing, silently: refused, facet named
    pill = make_object("pill")
    broken = Mesh(pill.vertices.copy(), pill.faces, "broken")
    broken.vertices[pill.faces[4, 1], 2] = np.nan
    write_stl(broken, tmp_path / "broken.stl")
    with pytest.raises(
        ConfigError, match=r"broken.stl: facet \d+ has a vertex that is not a finite"
    ):
        load_object(str(tmp_path / "broken.stl"))


def test_sphere_ground_truth_matches_the_analytic_cap():
    radius, depth, shape, center = 2.0, 0.8, (120, 140), (70.3, 55.7)
    gt = depth_map(
        sphere(radius), depth, shape, PX_PER_MM, max_penetration_mm=1.5, center_px=center
    )
    exact = sphere_cap_depth(shape, center, radius, depth)
    # facets of a 256 x 128 sphere sit < 0.3 µm inside it: < 1 µm in height up to 60° slopes
    assert np.abs(gt - exact).max() < 1e-3
    assert ((gt > 0) == (exact > 0)).mean() > 0.999
    # rotation about the (vertical) axis changes nothing for a sphere
    turned = depth_map(
        sphere(radius),
        depth,
        shape,
        PX_PER_MM,
        max_penetration_mm=1.5,
        center_px=center,
        rotation_deg=33.0,
    )
    assert np.abs(turned - exact).max() < 1e-3


def test_object_partly_outside_the_image_is_clipped():
    radius, depth, shape, center = 2.0, 1.0, (80, 60), (-10.0, 30.0)  # lowest point off-image
    gt = depth_map(
        sphere(radius), depth, shape, PX_PER_MM, max_penetration_mm=2.0, center_px=center
    )
    exact = sphere_cap_depth(shape, center, radius, depth)
    assert gt.shape == shape
    assert 0 < gt.max() < depth  # the deepest point is not in view
    assert np.abs(gt - exact).max() < 1e-3
    far = depth_map(
        sphere(radius), depth, shape, PX_PER_MM, max_penetration_mm=2.0, center_px=(500, 500)
    )
    assert not far.any()


def test_vertical_walls_give_finite_steps():
    # a 2 mm x 3 mm box: flat bottom, four vertical walls
    corners = np.array([[-1.0, -1.5], [1.0, -1.5], [1.0, 1.5], [-1.0, 1.5]])
    box = height_field_solid(corners, np.full(4, 1.0), 0.0, name="box")
    assert box.is_watertight() and box.volume == pytest.approx(6.0)
    center = (40.25, 40.4)
    gt = depth_map(box, 0.7, (81, 81), PX_PER_MM, max_penetration_mm=1.0, center_px=center)
    rows, cols = np.indices(gt.shape)
    inside = (np.abs(cols - center[0]) < 1.0 * PX_PER_MM) & (
        np.abs(rows - center[1]) < 1.5 * PX_PER_MM
    )
    assert np.all(np.isfinite(gt))
    np.testing.assert_allclose(gt[inside], 0.7, atol=1e-12)
    assert not gt[~inside].any()


def test_pawn_neck_is_shadowed_and_walls_are_finite(objects):
    p = PawnParams()
    surface = surface_height(objects["pawn"], (160, 260), PX_PER_MM)
    gt = surface.depth(1.5, max_penetration_mm=2.0)
    assert np.all(np.isfinite(gt)) and gt.max() <= 1.5 and gt.min() == 0
    cy, cx = (160 - 1) / 2, (260 - 1) / 2
    neck_x = (6.25 - 5.0) * PX_PER_MM + cx  # neck at 6.1-6.43 mm from the base face
    head_x = (p.length_mm - p.head_radius_mm - 5.0) * PX_PER_MM + cx
    row = int(round(cy))
    assert gt[row, int(round(neck_x))] == 0  # 1.7 mm above the base rim: never touches at 1.5 mm
    expected_head = 1.5 - (p.base_radius_mm - p.head_radius_mm)
    assert gt[row, int(round(head_x))] == pytest.approx(expected_head, abs=2e-3)
    # the base's flat face: a vertical wall where depth drops from ~1.5 mm to 0 in one pixel
    base_col = int(np.ceil(cx - 5.0 * PX_PER_MM))
    assert gt[row, base_col] > 1.4 and gt[row, base_col - 1] == 0


def test_too_deep_and_negative_indentations_are_refused():
    with pytest.raises(PenetrationError, match="deeper than the maximum penetration 1.5 mm"):
        depth_map(sphere(2.0), 2.0, (20, 20), PX_PER_MM, max_penetration_mm=1.5)
    with pytest.raises(PenetrationError, match=">= 0"):
        depth_map(sphere(2.0), -0.1, (20, 20), PX_PER_MM, max_penetration_mm=1.5)
    surface = surface_height(sphere(2.0), (20, 20), PX_PER_MM)
    with pytest.raises(PenetrationError):
        surface.depth(3.0, max_penetration_mm=2.5)
    assert not surface.depth(0.0).any()
    with pytest.raises(ConfigError, match="px_per_mm"):
        surface_height(sphere(2.0), (20, 20), 0.0)


def test_linear_pose_matches_scale_and_rotation_and_mirrors_exactly(objects):
    """A registration's linear map: px/mm times a rotation is the rotated pose; a mirroring map
    (a flipped camera) gives the mirror image, not an empty raster; a singular map is refused."""
    pawn, shape, center = objects["pawn"], (150, 200), (99.5, 74.5)
    c, s = np.cos(np.radians(25.0)), np.sin(np.radians(25.0))
    turned = surface_height(pawn, shape, PX_PER_MM, center, 25.0)
    linear = surface_height(pawn, shape, 1.0, center, 0.0, PX_PER_MM * np.array([[c, -s], [s, c]]))
    np.testing.assert_array_equal(turned.height_mm, linear.height_mm)
    assert linear.rotation_deg == pytest.approx(25.0) and linear.px_per_mm == pytest.approx(19.5)
    plain = surface_height(pawn, shape, PX_PER_MM, center).depth(1.0)
    mirrored = surface_height(pawn, shape, 1.0, center, 0.0, PX_PER_MM * np.diag([-1.0, 1.0]))
    assert (plain > 0).sum() > 1000
    np.testing.assert_allclose(mirrored.depth(1.0), plain[:, ::-1], atol=1e-9)
    # an anisotropic map stretches the footprint by its scale along each axis
    wide = surface_height(pawn, shape, 1.0, center, 0.0, np.diag([1.0, 1.2]) * PX_PER_MM)
    assert (wide.depth(1.0) > 0).sum() == pytest.approx(1.2 * (plain > 0).sum(), rel=0.03)
    with pytest.raises(ConfigError, match="singular"):
        surface_height(pawn, shape, 1.0, center, 0.0, np.zeros((2, 2)))


def test_on_a_domed_gel_the_truth_is_the_depth_below_the_undeformed_dome(objects):
    """A DIGIT's dome falls away from the object off its apex: the ground truth is the rigid
    overlap with the undeformed dome, max(0, d - h - (sag - sag under the centre)). The same
    object pressed at the apex of a dome differs from the flat truth only by the dome's own sag."""
    pawn = objects["pawn"]
    shape, center = (160, 200), (60.3, 80.6)
    dome = {"kx_per_mm": 0.013, "ky_per_mm": 0.0043, "apex_x_mm": 0.0, "apex_y_mm": 0.0}
    flat = surface_height(pawn, shape, PX_PER_MM, center)
    domed = surface_height(pawn, shape, PX_PER_MM, center, dome=dome)
    rows, cols = np.mgrid[0 : shape[0], 0 : shape[1]]

    def sag(c, r):
        return 0.013 * ((c - 99.5) / PX_PER_MM) ** 2 + 0.0043 * ((r - 79.5) / PX_PER_MM) ** 2

    expected = np.maximum(1.0 - flat.height_mm - (sag(cols, rows) - sag(*center)), 0.0)
    np.testing.assert_allclose(domed.depth(1.0), expected, atol=1e-12)
    assert domed.depth(1.0)[flat.covered].sum() != pytest.approx(flat.depth(1.0).sum(), rel=1e-3)
    # the apex side (right of the centre, toward the image centre) is pressed deeper than the far side
    right = domed.depth(1.0) - flat.depth(1.0)
    covered = flat.depth(1.0) > 0
    assert (
        right[covered & (cols > center[0] + 10)].mean()
        > 0
        > right[covered & (cols < center[0] - 10)].mean()
    )


@pytest.mark.parametrize(
    ("line", "message"),
    [
        ("vertex 0 0", r"\(2 numbers, need x y z\)"),
        ("vertex 1 2 3 4", r"\(4 numbers, need x y z\)"),
    ],
)
def test_an_ascii_vertex_line_needs_exactly_three_numbers(tmp_path, line, message):
    """Repro: `vertex 0 0` raised a bare numpy ValueError that named neither the file nor the line;
    `vertex 1 2 3 4` was read with its fourth number dropped."""
    lines = ["solid t", "facet normal 0 0 1", "outer loop", "vertex 0 0 0", line, "vertex 0 1 0"]
    path = tmp_path / "t.stl"
    path.write_text("\n".join([*lines, "endloop", "endfacet", "endsolid t"]))
    with pytest.raises(ConfigError, match=rf"t.stl:5: malformed vertex line '{line}' {message}"):
        read_mesh(path)


def test_a_closed_surface_that_encloses_no_volume_is_refused(tmp_path):
    """Repro: a triangle and its reverse is closed and consistently wound, so it was taken as a
    test object of zero volume and its 'depth map' was the indentation at every pixel."""
    sheet = Mesh(np.array([[0, 0, 0], [4, 0, 0], [0, 4, 0]], float), [[0, 1, 2], [0, 2, 1]], "s")
    path = write_stl(sheet, tmp_path / "sheet.stl")
    assert read_mesh(path).is_watertight()
    with pytest.raises(
        ConfigError, match="sheet.stl: the mesh's closed surface encloses no volume"
    ):
        load_object(str(path))
    assert load_object(str(write_stl(make_object("pill"), tmp_path / "pill.stl"))).volume > 0


@pytest.mark.parametrize("name", ["hemispheres", "pill", "pawn"])
def test_the_z_buffer_is_trimesh_ray_casting(name):
    """The ground truth's gel-facing surface against trimesh's own ray casting: a ray up (+z) from
    below every pixel centre first meets that surface, at the height the z-buffer holds."""
    import trimesh

    mesh = make_object(name)
    shape, px_per_mm, centre, turn = (60, 80), 4.0, (40.3, 29.6), 20.0
    surface = surface_height(mesh, shape, px_per_mm, centre, turn)
    posed = trimesh.Trimesh(pose_vertices(mesh, px_per_mm, centre, turn), mesh.faces, process=False)
    rows, cols = np.mgrid[0 : shape[0], 0 : shape[1]]
    origins = np.column_stack([cols.ravel(), rows.ravel(), np.full(rows.size, -1.0)])
    up = np.tile([0.0, 0.0, 1.0], (rows.size, 1))
    hits, ray, _ = posed.ray.intersects_location(origins, up, multiple_hits=False)
    cast = np.full(rows.size, np.inf)
    cast[ray] = hits[:, 2]
    cast = cast.reshape(shape)
    np.testing.assert_array_equal(np.isfinite(cast), surface.covered)
    np.testing.assert_allclose(surface.height_mm[surface.covered], cast[surface.covered], atol=1e-9)


def test_a_users_mesh_arrives_in_any_format_trimesh_reads_and_inside_out_is_turned(tmp_path):
    """STL, OBJ, PLY and OFF read alike (trimesh); the same pill in each is the same object, and
    one wound inside out is turned outward (its volume positive, its surface as before)."""
    pill = make_object("pill")
    inside_out = Mesh(pill.vertices, pill.faces[:, ::-1], "pill")
    assert inside_out.volume < 0 and inside_out.is_watertight()
    reference = load_object("pill")
    for suffix in (".stl", ".obj", ".ply", ".off"):
        path = tmp_path / f"pill{suffix}"
        inside_out.trimesh().export(path)
        got = load_object(str(path))
        assert got.is_watertight() and got.volume == pytest.approx(reference.volume, rel=1e-5)
        np.testing.assert_allclose(got.bounds, reference.bounds, atol=1e-5)
    with pytest.raises(ConfigError, match=r"nor a mesh file \(.stl, .obj, .ply, .off\)"):
        load_object(str(tmp_path / "pill.step"))
