"""The paper's three test objects as parametric CAD, and loading a user's own STL.

Every object is returned in the **press frame**: x, y in the gel plane (mm, x along image columns,
y along image rows), z away from the gel, the face pressed into the gel pointing to -z, the lowest
point at z = 0 and the x-y bounding box centred on the origin. A user's STL is brought into the same
frame (re-centred, lowest point to z = 0) but never rotated: model it with its contact side down.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from threedcal.errors import ConfigError
from threedcal.evaluate.mesh import (
    Mesh,
    height_field_solid,
    read_solid,
    revolve,
    rotation_x,
    rotation_y,
)
from threedcal.object_refs import BUILTIN_OBJECTS, object_problem

OBJECT_NAMES = BUILTIN_OBJECTS


@dataclass(frozen=True)
class HemispheresParams:
    """Hemispheres of different radii standing on a square plate, pressed hemispheres first."""

    plate_mm: float = 10.0
    plate_thickness_mm: float = 1.0
    # (centre x, centre y, radius) in mm, plate centred on the origin (print orientation, y up)
    hemispheres: tuple[tuple[float, float, float], ...] = (
        (-2.3, -2.3, 2.5),
        (2.6, -2.6, 2.0),
        (-2.6, 2.8, 1.5),
        (2.5, 2.5, 1.0),
    )
    grid_mm: float = 0.25  # plate sampling
    arc_mm: float = 0.08  # sampling along each hemisphere's rim and meridians


@dataclass(frozen=True)
class PillParams:
    """A capsule (cylinder with hemispherical ends) lying flat, its axis along x."""

    length_mm: float = 10.0
    diameter_mm: float = 4.0
    sections: int = 192
    arc_points: int = 48


@dataclass(frozen=True)
class PawnParams:
    """A chess pawn (solid of revolution) lying on its side, its axis along x, base at -x.

    Profile from the base upwards: a flat-faced base disc, a tapering concave body, a collar,
    a narrow neck and a spherical head. Lying down it rests on the base rim; the neck stays in
    the shadow of the collar and head, and the base's flat faces are vertical walls.
    """

    length_mm: float = 10.0
    base_radius_mm: float = 2.6
    base_height_mm: float = 1.2
    body_bottom_radius_mm: float = 2.1
    body_top_radius_mm: float = 1.2
    body_top_mm: float = 5.6
    body_curve: float = 1.8  # > 1: concave flank
    collar_radius_mm: float = 1.9
    collar_height_mm: float = 0.5
    neck_radius_mm: float = 0.9
    head_radius_mm: float = 1.9
    sections: int = 192


PARAMS = {"hemispheres": HemispheresParams, "pill": PillParams, "pawn": PawnParams}


def hemispheres(params: HemispheresParams = HemispheresParams()) -> Mesh:
    half = params.plate_mm / 2
    n_grid = int(round(params.plate_mm / params.grid_mm)) + 1
    g = np.linspace(-half, half, n_grid)
    gx, gy = np.meshgrid(g, g)
    grid = np.column_stack([gx.ravel(), gy.ravel()])
    keep = np.ones(len(grid), dtype=bool)
    points, heights = [], []
    for cx, cy, r in params.hemispheres:
        if r <= 0 or abs(cx) + r > half or abs(cy) + r > half:
            raise ConfigError(f"hemispheres: hemisphere ({cx}, {cy}, r={r}) must lie on the plate")
        keep &= np.hypot(grid[:, 0] - cx, grid[:, 1] - cy) > r + 0.6 * params.grid_mm
        # rings of constant polar angle, so the steep rim is sampled densely in z. The outer band
        # (radius > r/2), where rings crowd radially, keeps the rim's point count with corners
        # aligned: staggered crowded rings would let Delaunay triangles bridge the rim.
        n_rings = max(4, int(np.ceil((np.pi / 2 * r) / params.arc_mm)))
        theta = np.linspace(0, np.pi / 2, n_rings + 1)
        n_rim = max(12, int(np.ceil(2 * np.pi * r / params.arc_mm)))
        points.append([[cx, cy]])
        heights.append([r])
        for k, t in enumerate(theta[1:], start=1):
            rho = r * np.sin(t)
            if rho > r / 2:
                n_around, stagger = n_rim, 0.0
            else:
                n_around, stagger = max(6, int(np.ceil(2 * np.pi * rho / params.arc_mm))), k % 2
            phi = 2 * np.pi * (np.arange(n_around) + 0.5 * stagger) / n_around
            points.append(np.column_stack([cx + rho * np.cos(phi), cy + rho * np.sin(phi)]))
            heights.append(np.full(n_around, r * np.cos(t)))
    for i, (ax, ay, ar) in enumerate(params.hemispheres):
        for bx, by, br in params.hemispheres[i + 1 :]:
            if np.hypot(ax - bx, ay - by) < ar + br + params.grid_mm:
                raise ConfigError("hemispheres: hemispheres overlap or touch")
    xy = np.vstack([grid[keep], *points])
    top = np.concatenate([np.zeros(keep.sum()), *heights]) + params.plate_thickness_mm
    solid = height_field_solid(xy, top, 0.0, name="hemispheres")
    _check_rims(solid, xy, params)
    # print orientation (plate on the bed) → press frame (hemispheres toward the gel, -z)
    return solid.transformed(rotation_x(180.0)).normalised()


def _check_rims(solid: Mesh, xy: np.ndarray, params: HemispheresParams) -> None:
    """No triangle may bridge a hemisphere's rim (one corner inside, one outside)."""
    n = len(xy)
    top_faces = solid.faces[np.all(solid.faces < n, axis=1)]
    for cx, cy, r in params.hemispheres:
        rho = np.hypot(xy[:, 0] - cx, xy[:, 1] - cy)
        inside = rho < r * (1 - 1e-9)
        outside = rho > r * (1 + 1e-9)
        bad = inside[top_faces].any(axis=1) & outside[top_faces].any(axis=1)
        if bad.any():
            raise ConfigError(
                f"hemispheres: {bad.sum()} triangles bridge the rim of the r={r} hemisphere; "
                "use a finer arc_mm or a coarser grid_mm"
            )


def pill(params: PillParams = PillParams()) -> Mesh:
    r, length = params.diameter_mm / 2, params.length_mm
    if not 0 < 2 * r <= length:
        raise ConfigError(f"pill: need 0 < diameter <= length, got {params.diameter_mm}, {length}")
    t = np.linspace(0, np.pi / 2, params.arc_points + 1)
    lower = np.column_stack([r - r * np.cos(t), r * np.sin(t)])
    upper = np.column_stack([length - r + r * np.sin(t), r * np.cos(t)])
    upper[-1] = [length, 0.0]
    if 2 * r == length:  # a sphere: the two arcs meet
        upper = upper[1:]
    solid = revolve(np.vstack([lower, upper]), params.sections, name="pill")
    return solid.transformed(rotation_y(90.0)).normalised()


def pawn_profile(params: PawnParams = PawnParams()) -> np.ndarray:
    """(z, radius) points from the centre of the base face to the top of the head."""
    p = params
    head_centre = p.length_mm - p.head_radius_mm
    collar_top = p.body_top_mm + p.collar_height_mm
    if p.neck_radius_mm >= p.head_radius_mm:
        raise ConfigError("pawn: the neck must be narrower than the head")
    neck_top = head_centre - np.sqrt(p.head_radius_mm**2 - p.neck_radius_mm**2)
    if not 0 < p.base_height_mm < p.body_top_mm < collar_top < neck_top:
        raise ConfigError(
            "pawn: need 0 < base height < body top < collar top < neck top (head start); "
            f"got {p.base_height_mm}, {p.body_top_mm}, {collar_top}, {neck_top:.3f}"
        )
    s = np.linspace(0, 1, 40)
    body_z = p.base_height_mm + s * (p.body_top_mm - p.base_height_mm)
    body_r = (
        p.body_top_radius_mm
        + (p.body_bottom_radius_mm - p.body_top_radius_mm) * (1 - s) ** p.body_curve
    )
    start = np.arcsin(p.neck_radius_mm / p.head_radius_mm)
    phi = np.linspace(np.pi - start, 0, 60)  # angle from the +z axis, head centre
    head = np.column_stack(
        [head_centre + p.head_radius_mm * np.cos(phi), p.head_radius_mm * np.sin(phi)]
    )
    head[-1] = [p.length_mm, 0.0]
    profile = np.vstack(
        [
            [[0.0, 0.0], [0.0, p.base_radius_mm], [p.base_height_mm, p.base_radius_mm]],
            np.column_stack([body_z, body_r]),
            [[p.body_top_mm, p.collar_radius_mm], [collar_top, p.collar_radius_mm]],
            [[collar_top, p.neck_radius_mm]],
            head,
        ]
    )
    return profile


def pawn(params: PawnParams = PawnParams()) -> Mesh:
    solid = revolve(pawn_profile(params), params.sections, name="pawn")
    return solid.transformed(rotation_y(90.0)).normalised()


def make_object(name: str, **params) -> Mesh:
    """A built-in object by name, with optional CAD parameters overriding the defaults."""
    if name not in PARAMS:
        raise ConfigError(f"unknown test object {name!r} (built-in: {', '.join(OBJECT_NAMES)})")
    try:
        parsed = PARAMS[name](**params)
    except TypeError as exc:
        allowed = ", ".join(asdict(PARAMS[name]()))
        raise ConfigError(f"{name}: bad CAD parameter ({exc}); allowed: {allowed}") from exc
    return {"hemispheres": hemispheres, "pill": pill, "pawn": pawn}[name](parsed)


def load_object(ref: str | Path) -> Mesh:
    """A built-in name (`hemispheres`, `pill`, `pawn`) or a mesh file (STL, OBJ, PLY, OFF) → a
    mesh in the press frame."""
    ref = str(ref)
    if ref in PARAMS:
        return make_object(ref)
    problem = object_problem(ref)
    if problem:
        raise ConfigError(problem)  # a typo of a built-in name, or a missing file
    return read_solid(ref)  # what config check reads too (check_object_files)


def check_object_files(config: Mapping, source: str = "config") -> None:
    """Read every test-object mesh file of a validated config as the pressing stage will (a closed
    surface around a volume, finite corners) and check that no two objects of a scene share a
    name; raise one ConfigError naming each bad one by its key, before anything is collected."""
    problems = []
    for name, scene in config.get("scenes", {}).items():
        refs = scene.get("objects") or []
        for i, first in name_clashes(refs):
            problems.append(
                f"scenes.{name}.objects[{i}]: {str(refs[i])!r} has the name "
                f"{object_label(refs[i])!r}, as objects[{first}] has; rename one file"
            )
        for i, ref in enumerate(refs):
            if str(ref) in PARAMS:
                continue
            try:
                read_solid(ref)
            except ConfigError as exc:
                problems.append(f"scenes.{name}.objects[{i}]: {exc}")
    if problems:
        raise ConfigError(f"{source}: invalid config\n  " + "\n  ".join(problems))


def name_clashes(refs) -> list[tuple[int, int]]:
    """(index, index of the first with that name) for every object whose name (`object_label`)
    an earlier one has: tables, figures, mounts and exported files are keyed by the name."""
    first: dict[str, int] = {}
    clashes = []
    for i, ref in enumerate(refs):
        label = object_label(ref)
        if label in first:
            clashes.append((i, first[label]))
        first.setdefault(label, i)
    return clashes


def object_label(name_or_stl: str | Path) -> str:
    """Short name for tables: the built-in name or the STL file's stem."""
    ref = str(name_or_stl)
    return ref if ref in PARAMS else Path(ref).stem
