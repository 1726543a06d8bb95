"""How GelSimulator renders an elastic gel (gel.mechanics: elastic): the press's solution sampled
at the pixels, and its far field shaded to first order where it is gentle (threedcal.sim.elastic
solves the contact; threedcal.sim.optics holds the rest of the rendering)."""

from __future__ import annotations

import math

import numpy as np
from scipy.ndimage import map_coordinates

from threedcal.errors import ConfigError
from threedcal.sim.indenters import Indenter
from threedcal.sim.normals import surface_normals

LINEAR_SLOPE = 0.05  # elastic far field: shaded to first order where the deformation is this gentle
# ... and left out where its slope and height stay below these (the shading changes by < 0.5 DN:
# |dI/dslope| <= ~330 DN at the frame's brightest light, |dI/dz| <= ~12 DN/mm)
FAR_SLOPE = 1e-3
FAR_HEIGHT_MM = 0.03


class ElasticRendering:
    """GelSimulator's elastic-gel methods: they use the simulator's pixel grid (X, Y, Z0), its
    lights and its full shading (_exact_change, _shadow_box)."""

    def press(self, indenter: Indenter, center_px, rotation_deg: float, depth_mm: float):
        """The elastic contact solution (threedcal.sim.elastic.ElasticPress) of this pose, or None if the
        indenter does not touch the gel. Node coordinates are mm from the image centre."""
        if self._elastic is None:
            raise ConfigError(
                f"sensor profile {self.profile.get('name')!r} has gel.mechanics {self.mechanics!r}; "
                "an elastic press needs gel.mechanics: elastic"
            )
        pose = (indenter, float(center_px[0]), float(center_px[1]), float(rotation_deg))
        if self._press_memo is not None and self._press_memo[0] == (pose, float(depth_mm)):
            return self._press_memo[1]
        interference = self.interference(indenter, center_px, rotation_deg, depth_mm)
        ax, ay = self.axis_mm(center_px)
        reach = indenter.reach_mm
        press = self._elastic.press(
            interference, (ax - reach, ax + reach, ay - reach, ay + reach), (ax, ay)
        )
        self._press_memo = ((pose, float(depth_mm)), press)
        return press

    def axis_mm(self, center_px) -> tuple[float, float]:
        s = self.px_per_mm
        return (center_px[0] - self._cx) / s, (center_px[1] - self._cy) / s

    def interference(self, indenter: Indenter, center_px, rotation_deg: float, depth_mm: float):
        """w(X, Y): how far the indenter's surface lies below the undeformed (domed) gel surface (mm;
        -inf where it has no surface), at points (X, Y) mm from the image centre. Its lowest point
        sits `depth_mm` below the undeformed surface under its axis."""
        ax, ay = self.axis_mm(center_px)
        sag_c = float(self.sag_mm(ax, ay))
        c, sn = math.cos(math.radians(rotation_deg)), math.sin(math.radians(rotation_deg))

        def w(X, Y):
            dx, dy = X - ax, Y - ay
            if rotation_deg:
                dx, dy = c * dx + sn * dy, -sn * dx + c * dy
            gap = np.asarray(indenter.gap(dx, dy), dtype=np.float64)
            return depth_mm - gap - (np.asarray(self.sag_mm(X, Y), dtype=np.float64) - sag_c)

        return w

    def _elastic_window(self, press):
        """The pixels the press changes: its pressure grid plus the far field's visible reach."""
        X, Y = press.node_coords(press.node_box())
        s = self.px_per_mm
        reach = (
            press.reach_mm(slope=FAR_SLOPE, height_mm=FAR_HEIGHT_MM) * s + 3 * self.blur_sigma + 2
        )
        return self._clip_window(
            float(X.min()) * s + self._cx - reach,
            float(X.max()) * s + self._cx + reach,
            float(Y.min()) * s + self._cy - reach,
            float(Y.max()) * s + self._cy + reach,
        )

    def _elastic_surface(self, press, window) -> tuple[np.ndarray, np.ndarray]:
        """Gel surface (mm) and contact mask in `window`: the elastic displacement, sampled at each
        pixel's gel point by cubic interpolation between lattice nodes, never through the indenter;
        in contact (gel and indenter within the solver's and the interpolation's tolerance) the
        indenter itself."""
        y0, y1, x0, x1 = window
        X, Y = self.X[y0:y1, x0:x1], self.Y[y0:y1, x0:x1]
        box = press.nodes_covering(float(X.min()), float(X.max()), float(Y.min()), float(Y.max()))
        box = (box[0] - 2, box[1] + 2, box[2] - 2, box[3] + 2)  # the cubic's support
        u = self._sample_nodes(press.displacement_on(box), box, window, press)
        z = self.Z0[y0:y1, x0:x1] + u
        contact = np.zeros(u.shape, bool)
        # the indenter matters only where it was solved for (elsewhere it is above the gel)
        dom = press.node_box()
        step = press.spacing_mm
        nx, ny = press.node_coords(dom)
        inside = (
            (X >= float(nx.min()) - step)
            & (X <= float(nx.max()) + step)
            & (Y >= float(ny.min()) - step)
            & (Y <= float(ny.max()) + step)
        )
        rows, cols = np.nonzero(inside.any(axis=1))[0], np.nonzero(inside.any(axis=0))[0]
        if rows.size:
            r0, r1, c0, c1 = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
            w = press.interference_at(X[r0:r1, c0:c1], Y[r0:r1, c0:c1])
            ui = u[r0:r1, c0:c1]
            # never through the indenter: where the interpolated gel would pass through it, the gel
            # is the indenter. In contact the two agree to the solver's tolerance, so the gel leaves
            # the indenter where the interpolated elastic surface does, not at a lattice node
            with np.errstate(invalid="ignore"):
                gel_depth = np.maximum(ui, w)
                # touching: within the solver's tolerance and the interpolation's (~0.5 um)
                contact[r0:r1, c0:c1] = ui - w <= 2 * press.result.gap_tolerance_mm + 5e-4
            z[r0:r1, c0:c1] = self.Z0[y0:y1, x0:x1][r0:r1, c0:c1] + gel_depth
        return z.astype(np.float32), contact

    def _sample_nodes(self, values, box, window, press) -> np.ndarray:
        """`values` on the nodes of `press`'s lattice in `box` (row0, row1, col0, col1) at the pixels
        of `window`, by Catmull-Rom cubic interpolation (exact for quadratics).

        Today's pixels are a uniform grid along the lattice's axes, so the interpolation is separable
        with fixed weights. Pixels that are not (a lens) take a cubic spline at each pixel's gel point
        (X, Y) instead."""
        y0, y1, x0, x1 = window
        f = self._pixel_lattice
        if f is not None:
            # the pixel (fractional) where lattice node 0 sits, along x and along y
            ox, oy = (
                press.origin_mm[0] * self.px_per_mm + self._cx,
                press.origin_mm[1] * self.px_per_mm + self._cy,
            )
            cols = _upsample_axis(np.asarray(values, np.float32), box[2], ox, x0, x1, f, 1)
            return _upsample_axis(cols, box[0], oy, y0, y1, f, 0)
        bx, by = press.node_coords((box[0], box[0] + 1, box[2], box[2] + 1))
        rows = (self.Y[y0:y1, x0:x1] - float(by[0, 0])) / press.spacing_mm
        cols = (self.X[y0:y1, x0:x1] - float(bx[0, 0])) / press.spacing_mm
        return map_coordinates(
            np.asarray(values, np.float64), [rows, cols], order=3, mode="nearest"
        ).astype(np.float32)

    def _elastic_change(self, z, win, center_px) -> np.ndarray:
        """ΔI (unblurred) of an elastic gel: shaded in full where the deformation's slope exceeds
        LINEAR_SLOPE (the contact and its surroundings, where shadows fall too), to first order in
        the deformation (slope and height) elsewhere, with the Jacobian of the shading taken at the
        undeformed gel. The first-order error is ~ gain x slope^2 / 2: below 0.05 DN (tests/sim/test_sim_elastic.py)."""
        y0, y1, x0, x1 = win
        s = self.px_per_mm
        dz = z - self.Z0[y0:y1, x0:x1]
        dgy, dgx = np.gradient(dz, 1.0 / s)
        jx, jy, jz = (j[y0:y1, x0:x1] for j in self._jacobian)
        delta = np.multiply(jx, dgx[..., None])
        term = np.multiply(jy, dgy[..., None])
        delta += term
        delta += np.multiply(jz, dz[..., None], out=term)
        # in full where the deformation is not gentle, and wherever a shadow could start
        gx0, gy0 = (g[y0:y1, x0:x1] for g in self._g0)
        tan_min = min(li["tan_el"] for li in self._lights)
        steep = (dgx * dgx + dgy * dgy > LINEAR_SLOPE**2) | (
            np.square(dgx + gx0) + np.square(dgy + gy0) > (0.8 * tan_min) ** 2
        )
        rows, cols = np.nonzero(steep.any(axis=1))[0], np.nonzero(steep.any(axis=0))[0]
        if rows.size:
            pad = int(math.ceil(self.shadow_reach_mm * s)) + 2 if self.shadow_strength > 0 else 2
            h, w = z.shape
            r0, r1 = max(rows[0] - pad, 0), min(rows[-1] + 1 + pad, h)
            c0, c1 = max(cols[0] - pad, 0), min(cols[-1] + 1 + pad, w)
            sub = (y0 + r0, y0 + r1, x0 + c0, x0 + c1)
            gx = dgx[r0:r1, c0:c1] + gx0[r0:r1, c0:c1]
            gy = dgy[r0:r1, c0:c1] + gy0[r0:r1, c0:c1]
            zs = z[r0:r1, c0:c1]
            delta[r0:r1, c0:c1] = self._exact_change(
                zs, sub, center_px, (gx, gy), self._shadow_box(gx, gy)
            )
        return delta

    def _setup_linear_shading(self) -> None:
        """The Jacobian of the shaded intensity (DN) with respect to the surface slope (gx, gy) and
        height z at the undeformed gel, by central differences (elastic far field)."""
        gx0, gy0 = (g.astype(np.float32) for g in self._sag_gradient(self.X, self.Y))
        self._g0 = (gx0, gy0)

        def intensity(gx, gy, z):
            n = surface_normals(gx, gy)
            total = np.zeros(gx.shape + (3,), np.float32)
            for li, col, (resp, irr) in zip(
                self._lights, self._col, self._shading(self.X, self.Y, z, n, self._vig), strict=True
            ):
                total += irr[..., None] * li["scatter"] + (irr * li["gain"] * resp)[..., None] * col
            return total

        e = 1e-3
        self._jacobian = (
            (intensity(gx0 + e, gy0, self.Z0) - intensity(gx0 - e, gy0, self.Z0)) / (2 * e),
            (intensity(gx0, gy0 + e, self.Z0) - intensity(gx0, gy0 - e, self.Z0)) / (2 * e),
            (intensity(gx0, gy0, self.Z0 + e) - intensity(gx0, gy0, self.Z0 - e)) / (2 * e),
        )


def _upsample_axis(v, first: int, origin_px: float, p0: int, p1: int, f: int, axis: int):
    """Catmull-Rom values at pixels p0..p1-1 along `axis` from lattice nodes first, first + 1, ...
    (node k at pixel origin_px + k f), limited to the range of the two nodes around each pixel."""
    q = (np.arange(p0, p1) - origin_px) / f
    node = np.floor(q).astype(np.int64)
    t = (q - node).astype(np.float32)
    node -= first
    t2, t3 = t * t, t * t * t
    taps = (
        (-1, (-t3 + 2 * t2 - t) / 2),
        (0, (3 * t3 - 5 * t2 + 2) / 2),
        (1, (-3 * t3 + 4 * t2 + t) / 2),
        (2, (t3 - t2) / 2),
    )
    shape = [1, 1]
    shape[axis] = q.size
    out = None
    for offset, weight in taps:
        term = np.take(v, node + offset, axis=axis) * weight.reshape(shape)
        out = term if out is None else out + term
    # never beyond the two nodes around a pixel: no overshoot where the gel bends sharply (the foot
    # of a wall). Where it is smooth the cubic stays between them anyway, except at a crest between
    # two nodes, flattened by < s^2 u'' / 8 (in contact the indenter itself restores it)
    left, right = np.take(v, node, axis=axis), np.take(v, node + 1, axis=axis)
    return np.clip(out, np.minimum(left, right), np.maximum(left, right))
