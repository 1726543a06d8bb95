"""Closed triangle meshes: the test objects' CAD, and the mesh files a user brings.

`Mesh` is the small value the ground truth rasterises: vertices and faces, wound counter-clockwise
seen from outside (outward normals), so a closed mesh's signed volume is positive. The built-in
objects are made here (solids of revolution, a height field). Files, the volume and the watertight
check are trimesh's: it reads STL (binary or ASCII), OBJ, PLY and OFF, so a CAD export arrives as
it was saved (`MESH_SUFFIXES`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from threedcal.errors import ConfigError
from threedcal.object_refs import MESH_SUFFIXES


@dataclass(frozen=True)
class Mesh:
    """A triangle mesh in mm: ``vertices`` (V, 3) float64, ``faces`` (F, 3) int64 vertex indices."""

    vertices: np.ndarray
    faces: np.ndarray
    name: str = "mesh"

    def __post_init__(self) -> None:
        vertices = np.asarray(self.vertices, dtype=np.float64)
        faces = np.asarray(self.faces, dtype=np.int64)
        if vertices.ndim != 2 or vertices.shape[1] != 3:
            raise ConfigError(f"mesh {self.name!r}: vertices must be (V, 3), got {vertices.shape}")
        if faces.ndim != 2 or faces.shape[1] != 3 or len(faces) == 0:
            raise ConfigError(f"mesh {self.name!r}: faces must be (F, 3), F > 0, got {faces.shape}")
        if faces.min() < 0 or faces.max() >= len(vertices):
            raise ConfigError(f"mesh {self.name!r}: a face refers to a vertex that does not exist")
        if not np.all(np.isfinite(vertices)):
            raise ConfigError(f"mesh {self.name!r}: vertices must be finite")
        object.__setattr__(self, "vertices", vertices)
        object.__setattr__(self, "faces", faces)

    @property
    def triangles(self) -> np.ndarray:
        """(F, 3, 3): the corner coordinates of every face."""
        return self.vertices[self.faces]

    @property
    def bounds(self) -> np.ndarray:
        """(2, 3): lowest and highest x, y, z."""
        return np.stack([self.vertices.min(axis=0), self.vertices.max(axis=0)])

    @property
    def extent(self) -> np.ndarray:
        return np.ptp(self.vertices, axis=0)

    def trimesh(self):
        """The same mesh as a trimesh.Trimesh (vertices and faces as they are: not merged)."""
        import trimesh  # local: the Snakefile's parse imports this module; trimesh loads with a mesh

        return trimesh.Trimesh(self.vertices, self.faces, process=False, validate=False)

    @property
    def volume(self) -> float:
        """Signed volume; positive for a closed, outward-wound mesh."""
        with np.errstate(invalid="ignore", divide="ignore"):  # trimesh's centre of mass at 0
            return float(self.trimesh().volume)

    def is_watertight(self) -> bool:
        """Every edge is shared by exactly two faces that traverse it in opposite directions."""
        mesh = self.trimesh()
        return bool(mesh.is_watertight and mesh.is_winding_consistent)

    def transformed(self, rotation: np.ndarray | None = None, translation=(0.0, 0.0, 0.0)) -> Mesh:
        """x' = R x + t. A reflection (det R < 0) also reverses the winding to keep normals outward."""
        rot = np.eye(3) if rotation is None else np.asarray(rotation, dtype=np.float64)
        vertices = self.vertices @ rot.T + np.asarray(translation, dtype=np.float64)
        faces = self.faces if np.linalg.det(rot) > 0 else self.faces[:, ::-1]
        return Mesh(vertices, faces, self.name)

    def normalised(self) -> Mesh:
        """Centre the x-y bounding box on the origin and put the lowest point at z = 0."""
        lo, hi = self.bounds
        shift = -np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2]])
        return self.transformed(translation=shift)


def rotation_x(deg: float) -> np.ndarray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rotation_y(deg: float) -> np.ndarray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rotation_z(deg: float) -> np.ndarray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def revolve(profile: np.ndarray, sections: int = 128, name: str = "revolve") -> Mesh:
    """Solid of revolution about the z axis from a profile of (z, radius) points.

    The profile runs from one point on the axis (radius 0) to another, with radius > 0 in between;
    equal consecutive z give flat annular faces (vertical walls once the solid lies on its side).
    """
    profile = np.asarray(profile, dtype=np.float64)
    if profile.ndim != 2 or profile.shape[1] != 2 or len(profile) < 3:
        raise ConfigError(f"{name}: profile must be (N >= 3, 2) points of (z, radius)")
    if profile[0, 1] != 0 or profile[-1, 1] != 0 or np.any(profile[1:-1, 1] <= 0):
        raise ConfigError(f"{name}: profile must start and end on the axis with radius > 0 between")
    if np.any(np.all(np.diff(profile, axis=0) == 0, axis=1)):
        raise ConfigError(f"{name}: profile has repeated consecutive points")
    if sections < 3:
        raise ConfigError(f"{name}: sections must be >= 3, got {sections}")
    rings = profile[1:-1]
    phi = 2 * np.pi * np.arange(sections) / sections
    ring_xyz = np.stack(
        [
            rings[:, 1, None] * np.cos(phi),
            rings[:, 1, None] * np.sin(phi),
            np.broadcast_to(rings[:, 0, None], (len(rings), sections)),
        ],
        axis=-1,
    ).reshape(-1, 3)
    bottom = len(ring_xyz)
    top = bottom + 1
    vertices = np.vstack([ring_xyz, [0, 0, profile[0, 0]], [0, 0, profile[-1, 0]]])
    j = np.arange(sections)
    jn = (j + 1) % sections
    faces = [np.stack([np.full(sections, bottom), jn, j], axis=1)]
    for k in range(len(rings) - 1):
        a, b = k * sections + j, k * sections + jn
        c, d = (k + 1) * sections + jn, (k + 1) * sections + j
        faces += [np.stack([a, b, c], axis=1), np.stack([a, c, d], axis=1)]
    last = (len(rings) - 1) * sections
    faces.append(np.stack([last + j, last + jn, np.full(sections, top)], axis=1))
    mesh = Mesh(vertices, np.concatenate(faces), name)
    if profile[-1, 0] < profile[0, 0]:  # profile runs downwards: the winding is inside out
        mesh = Mesh(mesh.vertices, mesh.faces[:, ::-1], name)
    return mesh


def height_field_solid(
    points_xy: np.ndarray, top_z: np.ndarray, bottom_z: float, name: str = "height_field"
) -> Mesh:
    """A closed solid between z = bottom_z and z = top_z(x, y) over the Delaunay triangulation of the points.

    Top and bottom share one triangulation; its boundary edges are extruded into side walls, so
    the result is watertight whatever the point set.
    """
    # local: kept out of the Snakefile's parse (check_object_files)
    from scipy.spatial import Delaunay

    points_xy = np.asarray(points_xy, dtype=np.float64)
    top_z = np.asarray(top_z, dtype=np.float64)
    if np.any(top_z <= bottom_z):
        raise ConfigError(f"{name}: the top must lie above the bottom everywhere")
    tri = Delaunay(points_xy)
    if len(tri.coplanar):
        raise ConfigError(f"{name}: {len(tri.coplanar)} duplicate points in the height field")
    simplices = tri.simplices.astype(np.int64)
    p = points_xy[simplices]
    area2 = (p[:, 1, 0] - p[:, 0, 0]) * (p[:, 2, 1] - p[:, 0, 1]) - (p[:, 2, 0] - p[:, 0, 0]) * (
        p[:, 1, 1] - p[:, 0, 1]
    )
    simplices[area2 < 0] = simplices[area2 < 0][:, ::-1]  # counter-clockwise seen from +z
    n = len(points_xy)
    directed = np.concatenate([simplices[:, [0, 1]], simplices[:, [1, 2]], simplices[:, [2, 0]]])
    keys = directed[:, 0] * n + directed[:, 1]
    boundary = directed[~np.isin(directed[:, 1] * n + directed[:, 0], keys)]
    a_top, b_top = boundary[:, 0], boundary[:, 1]
    a_bot, b_bot = a_top + n, b_top + n
    vertices = np.vstack(
        [
            np.column_stack([points_xy, top_z]),
            np.column_stack([points_xy, np.full(n, bottom_z)]),
        ]
    )
    faces = np.concatenate(
        [
            simplices,
            simplices[:, ::-1] + n,
            np.stack([a_bot, b_bot, b_top], axis=1),
            np.stack([a_bot, b_top, a_top], axis=1),
        ]
    )
    return Mesh(vertices, faces, name)


# --- mesh files --------------------------------------------------------------------------------


def write_stl(mesh: Mesh, path: str | Path) -> Path:
    """Binary STL, what slicers and CAD tools read."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    mesh.trimesh().export(path, file_type="stl")
    return path


def read_mesh(path: str | Path, name: str | None = None) -> Mesh:
    """A mesh file (`MESH_SUFFIXES`) → Mesh; corners at identical coordinates become one vertex and
    faces that collapse to a line are dropped. A file trimesh cannot read, or a corner that is not
    a finite number, is an error naming the file (and the facet or line)."""
    import trimesh  # local: the Snakefile's parse imports this module; trimesh loads with a mesh

    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"mesh file {str(path)!r} does not exist")
    kind = path.suffix.lower()
    if kind not in MESH_SUFFIXES:
        raise ConfigError(f"{path}: not a mesh file ({', '.join(MESH_SUFFIXES)})")
    if kind == ".stl":
        _check_ascii_vertex_lines(path.read_bytes(), path)
    try:
        loaded = trimesh.load(path, file_type=kind[1:], force="mesh", process=False)
        corners = np.asarray(loaded.triangles, dtype=np.float64).reshape(-1, 3)
    except Exception as exc:  # noqa: BLE001 - any failure to read is one message naming the file
        reason = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise ConfigError(f"{path}: not a readable {kind[1:].upper()} file ({reason})") from None
    bad = np.flatnonzero(~np.isfinite(corners).all(axis=1))
    if bad.size:
        raise ConfigError(
            f"{path}: facet {bad[0] // 3 + 1} has a vertex that is not a finite number "
            f"({bad.size} such vertices in all)"
        )
    vertices, faces = np.unique(corners, axis=0, return_inverse=True)
    faces = faces.reshape(-1, 3)
    faces = faces[
        (faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])
    ]
    if len(faces) == 0:
        label = kind[1:].upper()
        raise ConfigError(f"{path}: no triangle read (an empty {label} file, or not one)")
    return Mesh(vertices, faces, name or path.stem)


def read_solid(path: str | Path) -> Mesh:
    """A test object's mesh file → a closed mesh wound outwards, in the press frame
    (`Mesh.normalised`)."""
    mesh = read_mesh(path)
    if not mesh.is_watertight():
        raise ConfigError(
            f"{path}: the mesh is not a closed (watertight), consistently wound surface; "
            "repair it (e.g. in your CAD tool or slicer) and export again"
        )
    if abs(mesh.volume) <= 1e-9 * max(float(np.prod(mesh.extent)), 1e-300):
        # e.g. a sheet and its reverse: closed, but nothing for the printer to press
        raise ConfigError(f"{path}: the mesh's closed surface encloses no volume")
    if mesh.volume < 0:  # wound inside out: turn the normals outwards
        mesh = Mesh(mesh.vertices, mesh.faces[:, ::-1], mesh.name)
    return mesh.normalised()


def _check_ascii_vertex_lines(raw: bytes, path: Path) -> None:
    """An ASCII STL's `vertex` lines hold exactly x y z: a short or long one is named by its line
    (a reader would fail without saying where, or drop the extra number)."""
    try:
        text = raw.decode("ascii")
    except UnicodeDecodeError:
        return  # binary
    if not text.lstrip().lower().startswith("solid"):
        return
    for number, line in enumerate(text.splitlines(), start=1):
        words = line.split()
        if words and words[0].lower() == "vertex":
            try:
                if len(words) != 4:
                    raise ValueError(f"{len(words) - 1} numbers, need x y z")
                [float(w) for w in words[1:]]
            except ValueError as exc:
                raise ConfigError(
                    f"{path}:{number}: malformed vertex line {line.strip()!r} ({exc})"
                ) from None
