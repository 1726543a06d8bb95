"""A physically grounded optical model of a vision-based tactile sensor (DIGIT, GelSight Mini).

What it models, and why (every constant comes from the sensor profile):

- Gel shape (`gel.mechanics`). `geometric`: inside the contact the gel surface *is* the indenter's
  surface (a sphere of radius R pressed d deep leaves a cap of radius a = sqrt(2Rd - d^2)), outside a
  low raised rim (the displaced volume of a nearly incompressible gel) whose width scales with the gel
  thickness, blended back to the dome over the same skirt width. `elastic`: the surface of a
  linear-elastic layer bonded to the acrylic, pressed by the rigid indenter (threedcal.sim.elastic):
  in contact it follows the indenter, outside it is the elastic solution — smooth over vertical walls,
  with the layer's own bulge. Either way depth is measured from the undeformed (domed) surface under
  the indenter axis, and repeated frames of one hold creep a little deeper (viscoelastic relaxation).
- Shading. Each LED sits at a finite distance at low elevation, so both its direction and its
  irradiance (1/r^2) depend on the pixel and on the local surface height: the position-dependent
  illumination the paper's xy inputs exist for. A diffuse (scattered) part lights the background
  independently of the normal; the directional part follows max(n.L, 0) plus a small quadratic term.
  Steep walls cast shadows on their far side from each light (horizon test along the line from the
  LED through the contact).
- Background and camera. Vignetting, LED hot spots, a fixed paint texture, optional markers; a
  Gaussian camera blur, per-frame gain flicker, per-pixel noise, and 8-bit rounding with clipping.

Speed: the background is rendered once; a frame re-shades only a window around the contact and adds
the change (blur is linear, so blurring the change alone is exact). An elastic gel's far field can
reach the whole frame: where it is gentle it is shaded to first order (the shading's Jacobian, taken
once at the undeformed gel), and cast shadows are traced only near steep slopes (a shadow needs a
slope steeper than the light's elevation within its reach). Noise comes from a bank of pre-drawn
fields picked and shifted per frame from (seed, frame_index).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import cv2
import numpy as np

from threedcal.errors import ConfigError
from threedcal.sim.background_field import background_field
from threedcal.sim.elastic import ElasticGel
from threedcal.sim.elastic_render import ElasticRendering
from threedcal.sim.indenters import Indenter
from threedcal.sim.layer_kernel import GelMaterial
from threedcal.sim.normals import surface_normals

MECHANICS = ("geometric", "elastic")

_NOISE_BANK = 6  # pre-drawn noise fields
_NOISE_PAD = 32  # random shift range of a noise field, px
SKIRT_EXTENT = 4.0  # the skirt ends (smoothly) this many skirt widths beyond the contact


def _stream(seed: int, *keys: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence([int(seed) & 0xFFFFFFFF, *keys]))


class GelSimulator(ElasticRendering):
    """Renders uint8 RGB frames (H, W, 3) of a sensor profile's gel; deterministic per (seed, frame).

    `image_size=(width, height)` and `px_per_mm` override the profile's frame (used to render at a
    real dataset's scale). Poses are in image pixels (x = column, y = row, sub-pixel), depths in mm.

    `seed` is the sensor's own draw: its paint texture, and by default the camera noise. A later
    session on the same sensor keeps the gel and paint but not the noise or the lighting:
    `noise_seed` draws the noise fields and per-frame picks apart from `seed`, and `gain_rgb`
    scales every frame per colour channel (the LEDs' brightness drifted since calibration).
    """

    def __init__(
        self,
        profile: Mapping[str, Any],
        seed: int = 0,
        *,
        image_size: tuple[int, int] | None = None,
        px_per_mm: float | None = None,
        noise_seed: int | None = None,
        gain_rgb=None,
        margin_px: int = 0,
    ):
        """`margin_px`: render this many pixels beyond the frame on every side (what a lens's
        camera sees past the ideal frame: threedcal.sim.camera); the profile's frame-relative
        constants (hot spots, the colour field, vignetting) stay those of the frame."""
        if profile.get("type") != "vision":
            raise ConfigError(f"sensor profile {profile.get('name')!r} is not a vision sensor")
        self.profile = profile
        self.seed = int(seed)
        self.noise_seed = self.seed if noise_seed is None else int(noise_seed)
        self.gain_rgb = None if gain_rgb is None else np.asarray(gain_rgb, dtype=np.float32)
        if self.gain_rgb is not None and (
            self.gain_rgb.shape != (3,)
            or not np.all(np.isfinite(self.gain_rgb) & (self.gain_rgb > 0))
        ):
            raise ConfigError(f"gain_rgb must be three positive numbers, got {gain_rgb!r}")
        w, h = image_size or (profile["image"]["width_px"], profile["image"]["height_px"])
        self.margin = int(margin_px)
        if self.margin < 0:
            raise ConfigError(f"margin_px must be >= 0, got {margin_px!r}")
        self.frame_width, self.frame_height = int(w), int(h)
        self.width, self.height = int(w) + 2 * self.margin, int(h) + 2 * self.margin
        self.px_per_mm = float(px_per_mm or profile["px_per_mm"])
        gel, optics = profile["gel"], profile["optics"]
        self.max_penetration_mm = float(gel["max_penetration_mm"])
        self.thickness_mm = float(gel["thickness_mm"])
        self.skirt_mm = float(gel.get("skirt_width_per_thickness", 0.15)) * self.thickness_mm
        self.rim_fraction = float(gel.get("rim_volume_fraction", 0.3))
        self.creep_fraction = float(gel.get("creep_fraction", 0.0))
        self.creep_frames = float(gel.get("creep_frames", 10.0))
        self.nonlinearity = float(optics.get("nonlinearity", 0.0))
        self.wrap = float(optics.get("wrap", 0.0))
        self.shadow_strength = float(optics.get("shadow_strength", 1.0))
        self.shadow_reach_mm = float(optics.get("shadow_reach_mm", math.inf))
        self.blur_sigma = float(optics.get("blur_sigma_px", 0.0))
        self.gain_jitter = float(optics.get("frame_gain_jitter", 0.0))
        self.noise_dn = np.asarray(optics.get("noise_dn", [0, 0, 0]), dtype=np.float32)
        self.noise_correlation_px = float(optics.get("noise_correlation_px", 0.0))
        dome = gel.get("dome")
        self._dome = None if dome is None else dict(dome)
        self.mechanics = str(gel.get("mechanics", "geometric"))
        if self.mechanics not in MECHANICS:
            raise ConfigError(
                f"sensor profile {profile.get('name')!r}: gel.mechanics {self.mechanics!r} is not "
                f"one of {', '.join(MECHANICS)}"
            )
        if self.mechanics == "elastic":
            material = GelMaterial.from_profile(gel)  # a missing constant fails before any set-up
        self._setup_geometry()
        self._setup_lights(profile["lights"])
        self._setup_background(optics)
        self._setup_noise()
        self._elastic = None
        if self.mechanics == "elastic":
            grid_px = int(gel.get("elastic_grid_px", 2))
            # a node every grid_px pixels, on a lattice through each press's axis (in mm: a lens
            # would only change where the pixels sample it)
            self._elastic = ElasticGel(
                material,
                grid_px / self.px_per_mm,
                tol=float(gel.get("elastic_tolerance", 1e-4)),
            )
            self._press_memo: tuple | None = None
            # pixels a uniform grid, grid_px of them per lattice step (as everything here assumes);
            # a lens would set None and sample each pixel's gel point instead
            self._pixel_lattice: int | None = grid_px
            self._setup_linear_shading()

    # ----------------------------------------------------------------- set-up (once per simulator)
    def _setup_geometry(self) -> None:
        s = self.px_per_mm
        self._cx, self._cy = (self.width - 1) / 2, (self.height - 1) / 2
        x = (np.arange(self.width, dtype=np.float32) - self._cx) / s
        y = (np.arange(self.height, dtype=np.float32) - self._cy) / s
        self.X, self.Y = np.meshgrid(x, y)
        self.Z0 = self.sag_mm(self.X, self.Y).astype(np.float32)
        gx0, gy0 = self._sag_gradient(self.X, self.Y)
        self._n0 = surface_normals(gx0, gy0)
        half_diag = math.hypot(self.frame_width - 1, self.frame_height - 1) / 2 / s
        self._rho2 = (self.X**2 + self.Y**2) / half_diag**2  # 1 at the frame's corners

    @property
    def domed(self) -> bool:
        """True when the undeformed gel is a dome (profile gel.dome), False when flat."""
        return self._dome is not None

    def sag_mm(self, x_mm, y_mm):
        """Depth of the undeformed gel surface below its apex (0 for a flat gel), x/y from the centre."""
        if self._dome is None:
            return np.zeros_like(np.asarray(x_mm, dtype=np.float32))
        d = self._dome
        return (
            d["kx_per_mm"] * (x_mm - d.get("apex_x_mm", 0.0)) ** 2
            + d["ky_per_mm"] * (y_mm - d.get("apex_y_mm", 0.0)) ** 2
        )

    def _sag_gradient(self, x_mm, y_mm):
        if self._dome is None:
            return np.zeros_like(x_mm), np.zeros_like(y_mm)
        d = self._dome
        return (
            2 * d["kx_per_mm"] * (x_mm - d.get("apex_x_mm", 0.0)),
            2 * d["ky_per_mm"] * (y_mm - d.get("apex_y_mm", 0.0)),
        )

    def _setup_lights(self, lights) -> None:
        self._col = np.array([li["color_rgb"] for li in lights], dtype=np.float32)  # (L, 3)
        self._P = []  # LED positions (x, y, z toward the camera), mm from the image centre
        self._lights = []
        for li in lights:
            az, el = math.radians(li["azimuth_deg"]), math.radians(li["elevation_deg"])
            D = float(li["distance_mm"])
            P = np.array([D * math.cos(az), D * math.sin(az), D * math.tan(el)], dtype=np.float32)
            self._P.append(P)
            self._lights.append(
                {
                    "P": P,
                    "ref2": float(
                        P @ P
                    ),  # squared distance to the image centre: irradiance 1 there
                    "gain": float(li["gain_dn"]),
                    # diffuse light: one level (times the LED colour) or its own RGB (mixed in the gel)
                    "scatter": np.asarray(li["scatter_dn"], dtype=np.float32)
                    if isinstance(li["scatter_dn"], list)
                    else float(li["scatter_dn"]) * np.asarray(li["color_rgb"], dtype=np.float32),
                    "tan_el": math.tan(el),
                }
            )
        self._scatter = np.stack([li["scatter"] for li in self._lights]).astype(np.float32)

    def _shading(self, X, Y, Z, n, vig):
        """Per-light directional response and irradiance at surface points (X, Y, Z) with normals n."""
        out = []
        for li in self._lights:
            P = li["P"]
            lx, ly, lz = P[0] - X, P[1] - Y, P[2] - Z
            r2 = lx * lx + ly * ly + lz * lz
            inv = 1.0 / np.sqrt(r2)
            ndotl = (n[0] * lx + n[1] * ly + n[2] * lz) * inv
            # an extended (diffused) LED still lights faces tilted a little past 90 degrees: wrap
            c = np.maximum((ndotl + self.wrap) * (1.0 / (1.0 + self.wrap)), 0.0)
            resp = c + self.nonlinearity * c * c
            irr = (li["ref2"] / r2) * vig
            out.append((resp, irr))
        return out

    def _setup_background(self, optics) -> None:
        vig = (1.0 - float(optics.get("vignetting", 0.0)) * self._rho2).astype(np.float32)
        self._vig = vig
        amb = np.asarray(optics.get("ambient_dn", [0, 0, 0]), dtype=np.float32)
        bg = np.broadcast_to(amb * vig[..., None], (self.height, self.width, 3)).copy()
        self._resp0, self._irr0_full = [], []
        for li, col, (resp, irr) in zip(
            self._lights,
            self._col,
            self._shading(self.X, self.Y, self.Z0, self._n0, vig),
            strict=True,
        ):
            self._resp0.append(resp.astype(np.float32))
            self._irr0_full.append(irr.astype(np.float32))
            bg += irr[..., None] * li["scatter"] + (irr * li["gain"] * resp)[..., None] * col
        # frame pixels (a margin's pixels lie outside 0 .. width - 1)
        xx, yy = np.meshgrid(np.arange(self.width), np.arange(self.height))
        xx, yy = xx - self.margin, yy - self.margin
        diag = math.hypot(self.frame_width, self.frame_height)
        for spot in optics.get("hot_spots", []):
            d2 = (xx - spot["x"] * (self.frame_width - 1)) ** 2 + (
                yy - spot["y"] * (self.frame_height - 1)
            ) ** 2
            g = np.exp(-d2 / (2 * (spot["sigma"] * diag) ** 2)).astype(np.float32)
            bg += g[..., None] * np.asarray(spot["amplitude_dn"], dtype=np.float32)
        field = optics.get("background_field")
        if field:
            bg += background_field(
                self.frame_width,
                self.frame_height,
                int(field["degree"]),
                field["coefficients_dn"],
                margin=self.margin,
            )
        texture_dn = float(optics.get("texture_dn", 0.0))
        if texture_dn > 0:
            rng = _stream(self.seed, 1)
            tex = rng.standard_normal((self.height, self.width)).astype(np.float32)
            tex = cv2.GaussianBlur(tex, (0, 0), 1.5)
            tex *= texture_dn / max(float(tex.std()), 1e-6)
            bg += tex[..., None]
        markers = optics.get("markers")
        self._marker_mask = None
        if markers:
            s = self.px_per_mm
            pitch, rad = markers["spacing_mm"] * s, markers["radius_mm"] * s
            fx = (xx + self.margin - self._cx) / pitch
            fy = (yy + self.margin - self._cy) / pitch
            dist = np.hypot(fx - np.rint(fx), fy - np.rint(fy)) * pitch
            cover = np.clip(rad + 0.5 - dist, 0.0, 1.0)
            self._marker_mask = (1.0 - markers["darkness"] * cover).astype(np.float32)[..., None]
        self._bg = self._blur(bg.astype(np.float32))

    def _setup_noise(self) -> None:
        rng = _stream(self.noise_seed, 2)
        shape = (_NOISE_BANK, self.height + _NOISE_PAD, self.width + _NOISE_PAD, 3)
        fields = rng.standard_normal(shape, dtype=np.float32)
        if self.noise_correlation_px > 0:
            # a real camera's noise is not white (demosaicing, compression): neighbouring pixels
            # share it. Blurred per field, then rescaled so noise_dn stays the per-pixel std
            for k in range(_NOISE_BANK):
                fields[k] = cv2.GaussianBlur(
                    fields[k], (0, 0), self.noise_correlation_px, borderType=cv2.BORDER_REFLECT
                )
                fields[k] /= fields[k].reshape(-1, 3).std(axis=0)
        self._noise = (fields * self.noise_dn).astype(np.float32)

    def _blur(self, img: np.ndarray) -> np.ndarray:
        if self.blur_sigma <= 0:
            return img
        return cv2.GaussianBlur(img, (0, 0), self.blur_sigma, borderType=cv2.BORDER_REPLICATE)

    # ----------------------------------------------------------------- per frame
    @property
    def background(self) -> np.ndarray:
        """The noiseless, unquantised no-contact image (float32, DN): what a long average converges to."""
        return self._bg

    def effective_depth_mm(self, depth_mm: float, hold_frame: int = 0) -> float:
        """The depth actually reached after `hold_frame` frames of one hold (creep), mm."""
        hold = max(int(hold_frame), 0)
        return depth_mm * (1 + self.creep_fraction * (1 - math.exp(-hold / self.creep_frames)))

    def blank(self, frame_index: int = 0) -> np.ndarray:
        """A no-contact frame: background, flicker, noise, quantisation."""
        return self._finish(self.ideal(), frame_index)

    def render(
        self,
        indenter: Indenter,
        center_px: tuple[float, float],
        rotation_deg: float = 0.0,
        depth_mm: float = 0.0,
        *,
        frame_index: int = 0,
        hold_frame: int = 0,
    ) -> np.ndarray:
        """A frame with `indenter` pressed `depth_mm` into the gel, its axis at `center_px` (x, y)."""
        frame = self.ideal(indenter, center_px, rotation_deg, depth_mm, hold_frame=hold_frame)
        return self._finish(frame, frame_index)

    def ideal(
        self,
        indenter: Indenter | None = None,
        center_px: tuple[float, float] = (0.0, 0.0),
        rotation_deg: float = 0.0,
        depth_mm: float = 0.0,
        *,
        hold_frame: int = 0,
    ) -> np.ndarray:
        """The noiseless frame in float32 DN (the background alone without an indenter): what the
        camera's lens (threedcal.sim.camera) sees before its sensor adds noise."""
        frame = self._bg.copy()
        if indenter is not None:
            self.check_depth(depth_mm)
            cx, cy = (float(v) for v in center_px)
            if not (math.isfinite(cx) and math.isfinite(cy) and math.isfinite(rotation_deg)):
                raise ConfigError(
                    f"pose must be finite, got center_px={center_px}, rotation_deg={rotation_deg}"
                )
            if depth_mm > 0:
                delta = self.contact_change(
                    indenter, (cx, cy), rotation_deg, self.effective_depth_mm(depth_mm, hold_frame)
                )
                if delta is not None:
                    (y0, y1, x0, x1), d = delta
                    frame[y0:y1, x0:x1] += d
        if self._marker_mask is not None:
            frame *= self._marker_mask  # the gel's printed markers hide what lies under them
        return frame

    def check_depth(self, depth_mm: float) -> None:
        if not math.isfinite(depth_mm) or depth_mm < 0:
            raise ConfigError(f"depth_mm must be a finite number >= 0, got {depth_mm!r}")
        if depth_mm > self.max_penetration_mm:
            raise ConfigError(
                f"depth_mm {depth_mm} exceeds the maximum safe penetration "
                f"{self.max_penetration_mm} mm of sensor profile {self.profile.get('name')!r} "
                "(gel.max_penetration_mm)"
            )

    def surface(
        self, indenter: Indenter, center_px, rotation_deg: float, depth_mm: float, window
    ) -> tuple[np.ndarray, np.ndarray]:
        """Gel surface depth (mm, toward the camera) in `window` (y0, y1, x0, x1) and the contact mask."""
        if self._elastic is not None:
            press = self.press(indenter, center_px, rotation_deg, depth_mm)
            if press is None:
                y0, y1, x0, x1 = window
                return self.Z0[y0:y1, x0:x1], np.zeros((y1 - y0, x1 - x0), bool)
            return self._elastic_surface(press, window)
        return self._geometric_surface(indenter, center_px, rotation_deg, depth_mm, window)

    def _geometric_surface(self, indenter, center_px, rotation_deg, depth_mm, window):
        y0, y1, x0, x1 = window
        X, Y = self.X[y0:y1, x0:x1], self.Y[y0:y1, x0:x1]
        s = self.px_per_mm
        ax, ay = (center_px[0] - self._cx) / s, (center_px[1] - self._cy) / s
        dx, dy = X - ax, Y - ay
        if rotation_deg:
            c, sn = math.cos(math.radians(rotation_deg)), math.sin(math.radians(rotation_deg))
            dx, dy = c * dx + sn * dy, -sn * dx + c * dy  # into the indenter's frame
        pen = depth_mm - indenter.gap(dx, dy)  # -inf where the indenter has no surface
        sag_c = float(self.sag_mm(ax, ay))
        z0 = self.Z0[y0:y1, x0:x1]
        # the gel is pushed where the indenter lies below its undeformed (domed) surface
        below = pen - (z0 - sag_c) if self.domed else pen
        contact = below > 0
        if not contact.any():
            return z0, contact
        a = None if self.domed else indenter.contact_radius_mm(depth_mm)
        if a is not None:
            t = np.maximum(np.sqrt(dx * dx + dy * dy) - a, 0.0)
        else:
            t = cv2.distanceTransform((~contact).astype(np.uint8), cv2.DIST_L2, 5) / s
            a = math.sqrt(contact.sum() / s**2 / math.pi)
        w = self.skirt_mm
        volume = float(np.sum(below[contact])) / s**2
        # a raised rim (incompressible gel) holding part of the displaced volume, slope at most 0.3
        amp = self.rim_fraction * volume / (2 * math.pi * math.e * (a * w + 2 * w * w))
        amp = min(amp, 0.3 * w / math.e)
        tw = t / w
        rim = -amp * tw * np.exp(1.0 - tw)
        # back to the undeformed surface over the skirt; exactly there at SKIRT_EXTENT widths
        taper = np.square(np.clip(1.0 - tw * (1.0 / SKIRT_EXTENT), 0.0, 1.0))
        z_out = z0 + rim * taper  # the contact's edge lies on the undeformed surface
        with np.errstate(invalid="ignore"):
            z = np.maximum(sag_c + pen, z_out)  # never through the indenter; equal to it in contact
        return z.astype(np.float32), contact

    def window(self, indenter: Indenter, center_px, depth_mm: float, rotation_deg: float = 0.0):
        """Pixel bounds (y0, y1, x0, x1) of the region a contact can change, or None off the frame."""
        if self._elastic is not None:
            press = self.press(indenter, center_px, rotation_deg, depth_mm)
            return None if press is None else self._elastic_window(press)
        s = self.px_per_mm
        # on a dome the contact is not the flat one: it reaches toward the apex
        a = None if self.domed else indenter.contact_radius_mm(depth_mm)
        reach = (indenter.reach_mm if a is None else a) + SKIRT_EXTENT * self.skirt_mm
        margin = reach * s + 3 * self.blur_sigma + 2
        return self._clip_window(
            center_px[0] - margin,
            center_px[0] + margin,
            center_px[1] - margin,
            center_px[1] + margin,
        )

    def _clip_window(self, x0: float, x1: float, y0: float, y1: float):
        """Integer pixel bounds (y0, y1, x0, x1) covering [x0, x1] x [y0, y1] px, clipped to the frame."""
        x0 = max(int(math.floor(x0)), 0)
        x1 = min(int(math.ceil(x1)) + 1, self.width)
        y0 = max(int(math.floor(y0)), 0)
        y1 = min(int(math.ceil(y1)) + 1, self.height)
        if x1 - x0 < 3 or y1 - y0 < 3:
            return None
        return y0, y1, x0, x1

    # ----------------------------------------------------------------- shading
    def contact_change(self, indenter: Indenter, center_px, rotation_deg: float, depth_mm: float):
        """((y0, y1, x0, x1), ΔI float32) the contact adds to the background, or None if no contact."""
        win = self.window(indenter, center_px, depth_mm, rotation_deg)
        if win is None:
            return None
        z, contact = self.surface(indenter, center_px, rotation_deg, depth_mm, win)
        # an elastic gel deforms around a contact just off the frame too
        if not contact.any() and self._elastic is None:
            return None
        return win, self._shade_change(z, win, center_px)

    def _shade_change(self, z: np.ndarray, win, center_px) -> np.ndarray:
        """ΔI (float32, blurred) of the gel surface `z` in `win` against the background."""
        if self._elastic is None:
            return self._blur(self._exact_change(z, win, center_px))
        return self._blur(self._elastic_change(z, win, center_px))

    def _exact_change(self, z, win, center_px, gradient=None, shadow_box=None) -> np.ndarray:
        """ΔI (float32, unblurred) in `win`, every pixel shaded in full. `gradient` (gx, gy) if known;
        `shadow_box` (rows, cols of `win`) limits the shadow trace (None: the whole window)."""
        y0, y1, x0, x1 = win
        s = self.px_per_mm
        gx, gy = gradient if gradient is not None else np.gradient(z, 1.0 / s)[::-1]
        n = surface_normals(gx, gy)
        X, Y = self.X[y0:y1, x0:x1], self.Y[y0:y1, x0:x1]
        vig = self._vig[y0:y1, x0:x1]
        change = np.zeros(z.shape + (len(self._lights),), dtype=np.float32)
        scatter_change = np.zeros_like(change)
        contact_mm = ((center_px[0] - self._cx) / s, (center_px[1] - self._cy) / s)
        for i, (li, (resp, irr)) in enumerate(
            zip(self._lights, self._shading(X, Y, z, n, vig), strict=True)
        ):
            if shadow_box is None:
                resp = resp * self._lit(z, li, contact_mm)
            elif shadow_box:
                r0, r1, c0, c1 = shadow_box
                resp[r0:r1, c0:c1] *= self._lit(z[r0:r1, c0:c1], li, contact_mm)
            resp0 = self._resp0[i][y0:y1, x0:x1]
            irr0 = self._irr0_full[i][y0:y1, x0:x1]
            change[..., i] = li["gain"] * (irr * resp - irr0 * resp0)
            scatter_change[..., i] = irr - irr0
        delta = change @ self._col + scatter_change @ self._scatter  # (h, w, 3)
        return np.nan_to_num(delta, nan=0.0, posinf=0.0, neginf=0.0).astype(np.float32)

    def _shadow_box(self, gx: np.ndarray, gy: np.ndarray):
        """Where cast shadows can fall: around slopes steeper than 0.8 x the lowest light elevation
        (the margin covers finite differences), out to the shadows' reach. A shadow needs an occluder
        rising faster than tan(elevation) toward the light within its reach, so nothing outside this
        box is shadowed. () when no slope is that steep (a gentle dome is not)."""
        tan_min = min(li["tan_el"] for li in self._lights)
        steep = gx * gx + gy * gy > (0.8 * tan_min) ** 2
        rows, cols = np.nonzero(steep.any(axis=1))[0], np.nonzero(steep.any(axis=0))[0]
        if not rows.size or self.shadow_strength <= 0:
            return ()
        h, w = gx.shape
        pad = int(math.ceil(min(self.shadow_reach_mm * self.px_per_mm, max(h, w)))) + 2
        return (
            max(rows[0] - pad, 0),
            min(rows[-1] + 1 + pad, h),
            max(cols[0] - pad, 0),
            min(cols[-1] + 1 + pad, w),
        )

    def _lit(self, z: np.ndarray, li, contact_mm: tuple[float, float]) -> np.ndarray:
        """1 where the light reaches the surface, less in the cast shadow of a wall toward the light.

        The LED is a point at a finite distance, so its shadows fall along the line from the LED
        through the contact (`contact_mm`, from the image centre), as its shading does — not along
        one azimuth for the whole frame.

        Light in the gel scatters: a shadow only darkens the directional term by `shadow_strength`,
        and only within `shadow_reach_mm` of its wall (real gels show short, soft shadows).
        """
        span = float(z.max() - z.min())
        if self.shadow_strength <= 0 or span * self.px_per_mm < 0.5 * li["tan_el"]:
            return np.float32(1.0)
        s = self.px_per_mm
        reach_px = min(span / li["tan_el"] * s, self.shadow_reach_mm * s, max(z.shape))
        steps = int(min(16, max(2, math.ceil(reach_px / 1.5))))
        h, w = z.shape
        pad = int(math.ceil(reach_px)) + 1
        zp = np.pad(z, pad, mode="edge")
        toward = (li["P"][0] - contact_mm[0], li["P"][1] - contact_mm[1])
        ux, uy = (v / math.hypot(*toward) for v in toward)
        occl = np.full(z.shape, -np.inf, dtype=np.float32)
        for k in range(1, steps + 1):
            dist = reach_px * k / steps
            ox, oy = int(round(ux * dist)), int(round(uy * dist))
            if ox == 0 and oy == 0:
                continue
            shifted = zp[pad + oy : pad + oy + h, pad + ox : pad + ox + w]
            np.maximum(occl, shifted - z - (math.hypot(ox, oy) / s) * li["tan_el"], out=occl)
        return (1.0 - self.shadow_strength * (occl > 0)).astype(np.float32)

    def _finish(self, frame: np.ndarray, frame_index: int) -> np.ndarray:
        rng = _stream(self.noise_seed, 3, int(frame_index))
        k = int(rng.integers(_NOISE_BANK))
        oy, ox = (int(v) for v in rng.integers(_NOISE_PAD, size=2))
        gain = 1.0 + self.gain_jitter * float(rng.standard_normal())
        if gain != 1.0:
            frame *= np.float32(gain)
        if self.gain_rgb is not None:
            frame *= self.gain_rgb
        height, width = frame.shape[:2]
        frame += self._noise[k, oy : oy + height, ox : ox + width]
        frame += 0.5  # round half up on the cast below
        np.clip(frame, 0.0, 255.0, out=frame)
        return frame.astype(np.uint8)
