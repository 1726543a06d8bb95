"""The surface response of a linear-elastic gel layer bonded to a rigid backing (the acrylic): its
constants (GelMaterial) and the displacement a surface pressure causes (LayerKernel).

The gel is a linear-elastic layer of thickness h, Young's modulus E and Poisson ratio nu, bonded to a
rigid base, its free surface pressed by a rigid, frictionless indenter; the half-space is the limit
h -> inf. Only normal pressure acts on the surface (frictionless contact), so the surface's normal
displacement is the pressure convolved with the layer's surface Green's function.

Surface compliance (Fourier space). A normal pressure p cos(kx) on the surface of a layer bonded to a
rigid base displaces the surface by u = C(k) p cos(kx) with

    C(k) = 2 / (E* k) * S(kh),        E* = E / (1 - nu^2),

    S(t) = [(3 - 4nu) sinh 2t - 2t] / [(3 - 4nu) cosh 2t + 2t^2 + (1 + (3 - 4nu)^2) / 2].

S is derived from the Navier equations of a plane-strain Fourier mode (the rigid-base case of
Burmister's layered-system solution, J. Appl. Phys. 16, 89 and 126, 1945); the derivation, by sympy,
is `python -m diagnostics.elastic_gel derive`. Limits, each checked in tests/sim/test_sim_elastic.py:
S -> 1 for kh -> inf (Boussinesq half-space: C = 2/(E* k)); for kh -> 0 a compressible layer acts as
a Winkler foundation of constrained modulus M = E (1 - nu) / ((1 + nu)(1 - 2nu)), u = p h / M
(Johnson, Contact Mechanics, 1985, thin bonded layer); an incompressible one follows the lubrication
limit u = h^3 k^2 p / (3 mu) (pressure-driven flow in the layer, shear-free surface; the theory of
Chadwick, SIAM J. Appl. Math. 62, 1520, 2002).

A skin under tension. The gel's painted surface spreads a dent further than the bare layer does (real
contacts shade the gel well past their rim: docs/explanation/simulator.md). It is modelled as a membrane of tension
T (N/mm) on the layer: the pressure the layer carries is the applied pressure plus T times the surface's
Laplacian, so

    C_T(k) = C(k) / (1 + T k^2 C(k)).

On the node lattice k^2 is the 5-point Laplacian's symbol and C(k) the bare element table's DFT; the
skin's table is the inverse DFT of C_T on a periodic lattice, built once per gel and lattice for lags
out to the bare layer's own reach (RHO_MAX thicknesses, where its G is 0; further where a thin
layer's membrane reaches further) on a lattice twice that wide: a lag's images add nothing, and every
solve reads the same values whatever was solved before. T = 0 leaves the bare layer. With a skin the
shape at a given depth depends on T / (E* h), not on the depth alone.

Real-space kernel. Radially, the displacement per unit point force is

    G(r) = 1 / (pi E*) * [1 / r + g(r / h) / h],     g(rho) = int_0^inf (S(t) - 1) J0(rho t) dt,

the Boussinesq term plus a smooth, exponentially decaying correction (tabulated once per nu by
quadrature). On a square grid of spacing s the pressure is constant per element: the 1/r part is
integrated over the element in closed form (Love 1929; Johnson eq. 3.25), the smooth part by 3 x 3
Gauss points. A near-incompressible bonded layer answers a push with a raised ring around it (G < 0
beyond r ~ 0.9 h): the volume pushed down reappears nearby, the "pile-up" of a real gel.

Units: mm, MPa (N/mm^2), N.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from collections.abc import Mapping
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import scipy.fft as sfft
from scipy.special import j0

from threedcal.errors import ConfigError

_GAUSS3 = (np.array([-math.sqrt(0.6), 0.0, math.sqrt(0.6)]) / 2, np.array([5.0, 8.0, 5.0]) / 18)
_RHO_STEP = 0.01  # table spacing of g(rho), in layer thicknesses
# beyond this many thicknesses the layer's own response is below 1e-10 of its near field
RHO_MAX = 30.0
_SPECTRA = 24  # cached kernel spectra per kernel (one per FFT shape)
_SKIN_REACH = 8.0  # a thin layer's skin table reaches at least this many membrane lengths


@dataclass(frozen=True)
class GelMaterial:
    """The gel's elastic constants: E (MPa), nu, thickness (mm; math.inf for a half-space) and the
    tension of its surface skin (N/mm; 0 for a bare layer)."""

    youngs_modulus_mpa: float
    poisson_ratio: float
    thickness_mm: float = math.inf
    skin_tension_n_per_mm: float = 0.0

    def __post_init__(self):
        if not (math.isfinite(self.youngs_modulus_mpa) and self.youngs_modulus_mpa > 0):
            raise ConfigError(
                f"gel youngs_modulus_mpa must be > 0, got {self.youngs_modulus_mpa!r}"
            )
        if not (0.0 <= self.poisson_ratio <= 0.5):
            raise ConfigError(f"gel poisson_ratio must be in [0, 0.5], got {self.poisson_ratio!r}")
        if not (self.thickness_mm > 0):  # inf allowed
            raise ConfigError(f"gel thickness_mm must be > 0, got {self.thickness_mm!r}")
        t = self.skin_tension_n_per_mm
        if not (math.isfinite(t) and t >= 0):
            raise ConfigError(f"gel skin_tension_n_per_mm must be >= 0, got {t!r}")
        if t > 0 and math.isinf(self.thickness_mm):
            # the skin's table is built on a periodic lattice: a half-space's 1/r tail never dies out
            raise ConfigError("gel skin_tension_n_per_mm needs a finite thickness_mm (a layer)")

    @classmethod
    def from_profile(cls, gel: Mapping) -> GelMaterial:
        """From a sensor profile's `gel` section (youngs_modulus_mpa, poisson_ratio, thickness_mm,
        skin_tension_n_per_mm: 0 when absent)."""
        missing = [k for k in ("youngs_modulus_mpa", "poisson_ratio") if k not in gel]
        if missing:
            raise ConfigError(
                f"gel.mechanics 'elastic' needs gel.{' and gel.'.join(missing)} in the sensor profile"
            )
        return cls(
            float(gel["youngs_modulus_mpa"]),
            float(gel["poisson_ratio"]),
            float(gel["thickness_mm"]),
            float(gel.get("skin_tension_n_per_mm", 0.0)),
        )

    @property
    def plane_strain_modulus(self) -> float:
        """E* = E / (1 - nu^2), MPa."""
        return self.youngs_modulus_mpa / (1.0 - self.poisson_ratio**2)

    @property
    def shear_modulus(self) -> float:
        return self.youngs_modulus_mpa / (2.0 * (1.0 + self.poisson_ratio))


def layer_factor(kh, poisson_ratio: float) -> np.ndarray:
    """S(kh): the bonded layer's surface compliance over the half-space's (0 at kh = 0, 1 at inf)."""
    t = np.asarray(kh, dtype=np.float64)
    k3 = 3.0 - 4.0 * poisson_ratio
    out = np.ones_like(t)
    finite = t < 30.0  # beyond, S = 1 to double precision
    ts = t[finite]
    sech = 1.0 / np.cosh(2.0 * ts)
    num = k3 * np.tanh(2.0 * ts) - 2.0 * ts * sech
    den = k3 + (2.0 * ts * ts + 0.5 * (1.0 + k3 * k3)) * sech
    out[finite] = num / den
    return out


def surface_compliance(k, material: GelMaterial) -> np.ndarray:
    """C(k), mm per MPa: surface displacement of a unit pressure wave of wavenumber k (rad/mm)."""
    k = np.asarray(k, dtype=np.float64)
    with np.errstate(divide="ignore"):
        half_space = 2.0 / (material.plane_strain_modulus * k)
    if math.isinf(material.thickness_mm):
        return half_space
    s = layer_factor(k * material.thickness_mm, material.poisson_ratio)
    k0 = k == 0
    if k0.any():  # the limit k -> 0: the Winkler foundation (0 for an incompressible layer)
        nu = material.poisson_ratio
        winkler = (
            material.thickness_mm * (1 - 2 * nu) / (2 * material.shear_modulus * (1 - nu))
            if nu < 0.5
            else 0.0
        )
        half_space = np.where(k0, 0.0, half_space)
        return np.where(k0, winkler, half_space * s)
    return half_space * s


@lru_cache(maxsize=8)
def _layer_correction_table(poisson_ratio: float) -> np.ndarray:
    """g(rho) on rho = 0, _RHO_STEP, ..., RHO_MAX.

    Gauss-Legendre panels (8 nodes per 0.25 of t) over t < 24, where |S - 1| < 1e-18: the integrand is
    smooth, so the rule is exact to ~1e-12 (halving the panels changes no value by more)."""
    rho = np.arange(0.0, RHO_MAX + _RHO_STEP / 2, _RHO_STEP)
    x, wts = np.polynomial.legendre.leggauss(8)
    width = 0.25
    left = np.arange(0.0, 24.0, width)
    t = (left[:, None] + (x[None, :] + 1.0) * (width / 2)).ravel()
    f = (layer_factor(t, poisson_ratio) - 1.0) * np.tile(wts * (width / 2), left.size)
    out = np.empty_like(rho)
    for i in range(0, rho.size, 512):
        out[i : i + 512] = j0(np.outer(rho[i : i + 512], t)) @ f
    return out


def _love(x, y, c: float) -> np.ndarray:
    """Integral of 1/|r - r'| over the square |x'|, |y'| <= c, at (x, y) (Love 1929)."""

    def f(a, b):
        with np.errstate(divide="ignore", invalid="ignore"):
            v = a * np.arcsinh(b / np.abs(a))
        return np.where(a == 0, 0.0, v)

    def F(a, b):
        return f(a, b) + f(b, a)

    return F(x + c, y + c) - F(x + c, y - c) - F(x - c, y + c) + F(x - c, y - c)


class LayerKernel:
    """Surface displacement (mm) per unit pressure (MPa) on square elements of side `spacing_mm`.

    `influence(ny, nx)` holds every lag between two elements of an (ny, nx) grid; `spectrum(shape)`
    the FFT of that table laid out for a linear convolution on a zero-padded grid of `shape`.
    """

    def __init__(self, material: GelMaterial, spacing_mm: float):
        if not (math.isfinite(spacing_mm) and spacing_mm > 0):
            raise ConfigError(f"elastic grid spacing must be > 0 mm, got {spacing_mm!r}")
        self.material = material
        self.spacing_mm = float(spacing_mm)
        self._influence = np.zeros((0, 0))
        self._skin: np.ndarray | None = None
        self._spectra: OrderedDict[tuple[int, int], np.ndarray] = OrderedDict()

    def point(self, r_mm) -> np.ndarray:
        """G(r): displacement (mm) at distance r from a unit point force (N). With a skin: within the
        skin's table, the lattice's own response along a row (table / s^2, linear between nodes)."""
        r = np.asarray(r_mm, dtype=np.float64)
        m = self.material
        with np.errstate(divide="ignore"):
            out = 1.0 / r
        if not math.isinf(m.thickness_mm):
            out = out + self._g(r / m.thickness_mm) / m.thickness_mm
        out = out / (math.pi * m.plane_strain_modulus)
        if m.skin_tension_n_per_mm > 0:
            row = self._skin_table()[0]
            lags = np.arange(row.size) * self.spacing_mm
            near = r < lags[-1]
            out = np.where(near, np.interp(r, lags, row) / self.spacing_mm**2, out)
        return out

    def _g(self, rho: np.ndarray) -> np.ndarray:
        table = _layer_correction_table(self.material.poisson_ratio)
        inside = rho <= RHO_MAX
        with np.errstate(divide="ignore"):
            far = -1.0 / rho  # the layer's own response has died out: G = 0
        near = np.interp(rho, np.arange(table.size) * _RHO_STEP, table)
        return np.where(inside, near, far)

    def _element(self, ix: np.ndarray, iy: np.ndarray) -> np.ndarray:
        """Displacement at element centre offsets (ix, iy) (in elements) under unit pressure on one."""
        s, m = self.spacing_mm, self.material
        x, y = ix * s, iy * s
        out = _love(x, y, s / 2)
        if not math.isinf(m.thickness_mm):
            h = m.thickness_mm
            (q, wq) = _GAUSS3
            smooth = np.zeros_like(out)
            for qx, wx in zip(q, wq, strict=True):
                for qy, wy in zip(q, wq, strict=True):
                    rho = np.hypot(x - qx * s, y - qy * s) / h
                    smooth += wx * wy * self._g(rho)
            out = out + smooth * s * s / h
        return out / (math.pi * m.plane_strain_modulus)

    def influence(self, ny: int, nx: int) -> np.ndarray:
        """Table K[dy, dx] for lags 0..ny-1, 0..nx-1 (symmetric in the sign of each lag). With a
        skin, lags within its table come from it and the rest (where the skin no longer acts) from
        the bare layer: the same values whatever size was asked for first."""
        have = self._influence.shape
        if have[0] < ny or have[1] < nx:
            my, mx = max(ny, have[0]), max(nx, have[1])
            iy, ix = np.mgrid[0:my, 0:mx].astype(np.float64)
            table = self._element(ix, iy)
            if self.material.skin_tension_n_per_mm > 0:
                skin = self._skin_table()
                ky, kx = min(my, skin.shape[0]), min(mx, skin.shape[1])
                table[:ky, :kx] = skin[:ky, :kx]
            self._influence = table
        return self._influence[:ny, :nx]

    def _skin_table(self) -> np.ndarray:
        """The skin's table (module docstring), shared by every kernel of the same gel and lattice."""
        if self._skin is None:
            m = self.material
            self._skin = _skin_table(
                m.youngs_modulus_mpa,
                m.poisson_ratio,
                m.thickness_mm,
                m.skin_tension_n_per_mm,
                self.spacing_mm,
            )
        return self._skin

    def spectrum(self, shape: tuple[int, int], single: bool = False) -> np.ndarray:
        """rfft2 of the lag table in wrap-around order for a circular convolution of `shape`.

        Exact as a linear convolution for any source and target inside the same (ny, nx) box as
        long as shape >= (2 ny - 1, 2 nx - 1)."""
        key = (int(shape[0]), int(shape[1]), bool(single))
        hit = self._spectra.get(key)
        if hit is not None:
            self._spectra.move_to_end(key)
            return hit
        Ny, Nx = key[:2]
        hy, hx = (Ny + 1) // 2, (Nx + 1) // 2
        table = self.influence(hy, hx)
        wrap = np.zeros((Ny, Nx), np.float32 if single else np.float64)
        wrap[:hy, :hx] = table
        wrap[Ny - hy + 1 :, :hx] = table[1:][::-1]
        wrap[:hy, Nx - hx + 1 :] = table[:, 1:][:, ::-1]
        wrap[Ny - hy + 1 :, Nx - hx + 1 :] = table[1:, 1:][::-1, ::-1]
        spec = sfft.rfft2(wrap)
        self._spectra[key] = spec
        if len(self._spectra) > _SPECTRA:
            self._spectra.popitem(last=False)
        return spec

    def convolve(self, pressure: np.ndarray, single: bool = False) -> np.ndarray:
        """Displacement (mm) on the pressure's own grid (a linear convolution: the pressure is
        zero-padded to twice its size). `single`: in float32 (~1e-7 of the displacement, faster)."""
        ny, nx = pressure.shape
        fft_shape = (
            sfft.next_fast_len(2 * ny - 1, real=True),
            sfft.next_fast_len(2 * nx - 1, real=True),
        )
        spec = self.spectrum(fft_shape, single)
        padded = np.zeros(fft_shape, np.float32 if single else np.float64)
        padded[:ny, :nx] = pressure
        return sfft.irfft2(sfft.rfft2(padded) * spec, s=fft_shape)[:ny, :nx]


def _skin_length(material: GelMaterial) -> float:
    """How far (mm) a dent of the skin reaches, at least: the thickness, or a thin layer's own
    length where longer (a membrane on a compressible layer's Winkler foundation, sqrt(T h / M),
    or on an incompressible layer's lubrication flow, (T h^3 / (3 mu))^(1/4))."""
    m, t = material, material.skin_tension_n_per_mm
    h, nu = m.thickness_mm, m.poisson_ratio
    out = max(h, (t * h**3 / (3 * m.shear_modulus)) ** 0.25)
    if nu < 0.5:
        constrained = m.youngs_modulus_mpa * (1 - nu) / ((1 + nu) * (1 - 2 * nu))
        out = max(out, math.sqrt(t * h / constrained))
    return out


@lru_cache(maxsize=8)
def _skin_table(e: float, nu: float, h: float, t: float, s: float) -> np.ndarray:
    """The skin's table for lags out to the bare layer's own reach (RHO_MAX thicknesses, where its
    G is 0) or _SKIN_REACH skin lengths, whichever is longer, on both axes: the inverse DFT of C_T
    on a periodic lattice twice that wide. One fixed size, so every request reads the same values."""
    material = GelMaterial(e, nu, h, t)
    bare_kernel = LayerKernel(GelMaterial(e, nu, h), s)
    lags = math.ceil(max(RHO_MAX * h, _SKIN_REACH * _skin_length(material)) / s)
    n = sfft.next_fast_len(2 * lags)
    # the bare table in wrap-around order (lag |i|), evaluated on one quadrant and mirrored
    half = np.arange(n // 2 + 1, dtype=np.float64)
    quadrant = bare_kernel._element(half[None, :], half[:, None])
    fold = np.minimum(np.arange(n), n - np.arange(n))
    bare = sfft.rfft2(quadrant[np.ix_(fold, fold)])
    ky = 2 * np.pi * np.fft.fftfreq(n, d=s)
    kx = 2 * np.pi * np.fft.rfftfreq(n, d=s)
    lap = (4 / s**2) * (np.sin(ky[:, None] * s / 2) ** 2 + np.sin(kx[None, :] * s / 2) ** 2)
    table = sfft.irfft2(bare / (1 + t * lap * bare), s=(n, n))
    return _readonly_table(table[:lags, :lags])


def _readonly_table(table: np.ndarray) -> np.ndarray:
    out = np.ascontiguousarray(table)
    out.setflags(write=False)
    return out
