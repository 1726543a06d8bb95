"""Where a ball's contact lies on a domed gel relative to the ball's axis (docs/explanation/registration.md,
Domed gels)."""

from __future__ import annotations

import numpy as np
from scipy.interpolate import RegularGridInterpolator

from threedcal.dataset.contacts import Contact
from threedcal.dataset.labels import LocalDome
from threedcal.sim.elastic import ElasticGel, GelMaterial


class DomedContacts:
    """Where a ball's contact lies on a domed gel, relative to the ball's axis (what the affine maps).

    Off the apex the dome falls away from the ball, which meets the gel first on its apex side: the
    contact, and the centre a locator finds in it, lies toward the apex (by up to ~3.5 px on a
    DIGIT 0.4 mm deep). The affine would take that radial shift for a scale. The rigid overlap
    w = d − gap − (sag − sag under the axis) predicts it (docs/explanation/registration.md, Domed gels):

    - `area`: the centroid of w > 0, where the rim of a gel that follows the ball is centred;
    - `pressure`: the centroid of the pressure with which the ball presses w into an elastic layer
      of the gel's `material` (threedcal.sim.elastic), where the symmetric centre of an elastic
      contact lies. Solved on a coarse lattice of axes over the image once per depth (a few dozen
      solves), then interpolated: the shift varies smoothly, almost linearly, across the frame.

    Each located centre is moved to the axis whose predicted centre it is (a fixed point, three
    steps). Coordinates: pixels of an image of `image_shape` at `px_per_mm`; the dome (profile
    gel.dome) in mm about the image centre; `depth_mm` per frame, the press's depth below the gel
    as the plan meant it.
    """

    _GRID = 81  # samples across the ball's diameter (0.05 mm for R = 2 mm)
    _FIELD = (7, 9)  # axes (rows, columns) at which the pressure centroid is solved per depth
    _LATTICE_MM = 0.1  # the elastic solver's nodes: the simulator's 2 px at ~20 px/mm

    def __init__(
        self,
        dome,
        radius_mm: float,
        depth_mm,
        px_per_mm: float,
        image_shape,
        material: GelMaterial | None = None,
    ):
        self.kx, self.ky = float(dome["kx_per_mm"]), float(dome["ky_per_mm"])
        self.apex = (float(dome.get("apex_x_mm", 0.0)), float(dome.get("apex_y_mm", 0.0)))
        self.radius_mm = float(radius_mm)
        self.depth_mm = np.asarray(depth_mm, dtype=np.float64)
        self.px_per_mm = float(px_per_mm)
        height, width = image_shape[:2]
        self.shape = (height, width)
        self.centre_px = ((width - 1) / 2, (height - 1) / 2)
        half = self._GRID // 2  # a grid exactly symmetric about the axis: no centroid of its own
        g = self.radius_mm * (np.arange(-half, half + 1) / half)
        self._dx, self._dy = np.meshgrid(g, g)
        self.material = material
        self._gel = None
        self._fields: dict[float, object] = {}

    @property
    def elastic(self) -> bool:
        """True when the gel's elastic constants are known: its contacts are modelled as elastic."""
        return self.material is not None

    def _local_dome(self, ax: float, ay: float) -> LocalDome:
        """The dome about an axis at (ax, ay) mm from the image centre, as the labels see it."""
        return LocalDome(self.kx, self.ky, ax - self.apex[0], ay - self.apex[1])

    def _overlap(self, ax: float, ay: float, dx, dy, depth_mm: float):
        """w at (ax + dx, ay + dy) mm for a press with its axis at (ax, ay); -inf off the ball."""
        r2 = dx * dx + dy * dy
        root = np.sqrt(np.maximum(self.radius_mm**2 - r2, 0.0))
        w = depth_mm - (self.radius_mm - root) - self._local_dome(ax, ay).sag_mm(dx, dy)
        return np.where(r2 < self.radius_mm**2, w, -np.inf)

    def _axis_mm(self, axis_px) -> tuple[float, float]:
        return (
            (axis_px[0] - self.centre_px[0]) / self.px_per_mm,
            (axis_px[1] - self.centre_px[1]) / self.px_per_mm,
        )

    def _area_shift(self, ax: float, ay: float, depth_mm: float) -> np.ndarray:
        inside = self._overlap(ax, ay, self._dx, self._dy, depth_mm) > 0
        if not inside.any():
            return np.zeros(2)
        return np.array([self._dx[inside].mean(), self._dy[inside].mean()])

    def _pressure_shift(self, ax: float, ay: float, depth_mm: float) -> np.ndarray:
        if self._gel is None:
            self._gel = ElasticGel(self.material, self._LATTICE_MM)
        reach = self.radius_mm
        press = self._gel.press(
            lambda X, Y: self._overlap(ax, ay, X - ax, Y - ay, depth_mm),
            (ax - reach, ax + reach, ay - reach, ay + reach),
            (ax, ay),
        )
        if press is None:
            return np.zeros(2)
        X, Y = press.node_coords(press.node_box())
        p = press.pressure
        return np.array([(p * (X - ax)).sum(), (p * (Y - ay)).sum()]) / p.sum()

    def _pressure_field(self, depth_mm: float):
        key = round(float(depth_mm), 4)
        if key not in self._fields:
            rows, cols = self._FIELD
            ys = (np.linspace(0, self.shape[0] - 1, rows) - self.centre_px[1]) / self.px_per_mm
            xs = (np.linspace(0, self.shape[1] - 1, cols) - self.centre_px[0]) / self.px_per_mm
            shifts = np.array([[self._pressure_shift(x, y, key) for x in xs] for y in ys])
            self._fields[key] = RegularGridInterpolator(
                (ys, xs), shifts, bounds_error=False, fill_value=None
            )
        return self._fields[key]

    def contact_centre(self, axis_px, depth_mm: float, model: str = "area") -> np.ndarray:
        """Where the contact of a press with its axis at `axis_px`, `depth_mm` deep, is centred
        under `model` ("area" or "pressure")."""
        ax, ay = self._axis_mm(axis_px)
        if model == "pressure":
            shift = self._pressure_field(depth_mm)([[ay, ax]])[0]
        else:
            shift = self._area_shift(ax, ay, depth_mm)
        return np.asarray(axis_px, dtype=np.float64) + shift * self.px_per_mm

    def to_axis(self, contacts: list[Contact | None], model: str = "area") -> list[Contact | None]:
        """Each located centre moved to the axis of the press whose contact is centred there."""
        out = []
        for contact, depth in zip(contacts, self.depth_mm, strict=True):
            if contact is not None:
                seen = np.array([contact.x_px, contact.y_px])
                axis = seen.copy()
                for _ in range(3):
                    axis = axis + (seen - self.contact_centre(axis, depth, model))
                contact = Contact(
                    float(axis[0]), float(axis[1]), contact.radius_px, contact.strength
                )
            out.append(contact)
        return out

    def contacts_at(self, axes_px, model: str) -> np.ndarray:
        """The contact centres (N, 2) of presses whose axes lie at `axes_px`."""
        return np.array(
            [self.contact_centre(a, d, model) for a, d in zip(axes_px, self.depth_mm, strict=True)]
        )
