"""The elastic gel (threedcal.sim.elastic) against analytic and published contact mechanics, and its
use by the renderer (gel.mechanics: elastic)."""

import copy
import functools
import math

import numpy as np
import pytest
from scipy.integrate import quad
from scipy.optimize import brentq
from scipy.special import j0, j1

from threedcal.errors import ConfigError
from threedcal.profiles import load_profile
from threedcal.sim import elastic_render
from threedcal.sim.elastic import solve_contact
from threedcal.sim.indenters import Flat, Relief, Sphere
from threedcal.sim.layer_kernel import GelMaterial, LayerKernel, layer_factor, surface_compliance
from threedcal.sim.optics import GelSimulator


def square_grid(n: int, s: float):
    ax = np.arange(-n, n + 1) * s
    return np.meshgrid(ax, ax)


def contact_radius(result, s: float) -> float:
    return math.sqrt(result.contact.sum() * s * s / math.pi)


def paraboloid_contact(material, R, d, s, extent=1.15, tol=1e-6):
    """A paraboloid (Hertz's sphere) of radius R pressed d deep; the grid spans extent x sqrt(2Rd)."""
    n = int(math.ceil(extent * math.sqrt(2 * R * d) / s))
    X, Y = square_grid(n, s)
    return solve_contact(LayerKernel(material, s), d - (X**2 + Y**2) / (2 * R), tol=tol)


# ----------------------------------------------------------------- the layer's compliance
@pytest.mark.parametrize("nu", [0.0, 0.3, 0.45, 0.5])
def test_layer_compliance_has_the_published_limits(nu):
    # thick: the Boussinesq half-space, C = 2 / (E* k)
    assert layer_factor(40.0, nu) == pytest.approx(1.0, abs=1e-12)
    t = 1e-3
    if nu < 0.5:
        # thin, compressible: a Winkler foundation of constrained modulus M (Johnson 1985), u = p h / M
        m = GelMaterial(2.0, nu, 0.7)
        M = m.youngs_modulus_mpa * (1 - nu) / ((1 + nu) * (1 - 2 * nu))
        assert surface_compliance(np.array([0.0]), m)[0] == pytest.approx(0.7 / M, rel=1e-12)
        assert float(surface_compliance(np.array([t / 0.7]), m)[0]) == pytest.approx(
            0.7 / M, rel=1e-2
        )
    else:
        # thin, incompressible: the lubrication limit u = h^3 k^2 p / (3 mu), i.e. S -> 2 (kh)^3 / 3
        assert float(layer_factor(t, nu)) / t**3 == pytest.approx(2 / 3, rel=1e-3)
    # the layer is stiffer than the half-space at every wavelength
    ks = np.linspace(0.01, 10, 200)
    assert np.all(layer_factor(ks, nu) < 1) and np.all(np.diff(layer_factor(ks, nu)) > 0)


def disc_pressure(c, s):
    """Unit pressure on a disc of radius c, each element weighted by its covered fraction."""
    n = int(c / s) + 3
    X, Y = square_grid(n, s)
    sub = (np.arange(10) + 0.5) / 10 * s - s / 2
    cover = sum(((X + dx) ** 2 + (Y + dy) ** 2 <= c * c).astype(float) for dx in sub for dy in sub)
    return cover / 100, n


@pytest.mark.parametrize("nu, h", [(0.5, 1.0), (0.3, 1.0), (0.5, 0.3), (0.3, 0.3)])
def test_kernel_displaces_a_uniform_disc_as_the_hankel_transform_says(nu, h):
    """Uniform pressure on a disc of radius c: u(0) = int C(k) c J1(kc) dk, u(c) adds J0(kc). The
    reference integrates the closed-form compliance (its half-space part exactly, the rest by
    quadrature) — independent of the tabulated real-space kernel and its element integration."""
    material, c, s = GelMaterial(1.0, nu, h), 1.0, 0.04
    p, n = disc_pressure(c, s)
    u = LayerKernel(material, s).convolve(p)
    es = material.plane_strain_modulus

    def layer_part(extra):
        f = lambda k: 2 / es * (float(layer_factor(k * h, nu)) - 1) * c * j1(k * c) / k * extra(k)  # noqa: E731
        return quad(f, 0, 40 / h, limit=2000)[0]

    centre = 2 * c / es + layer_part(lambda k: 1.0)
    edge = 4 * c / (math.pi * es) + layer_part(lambda k: j0(k * c))
    scale = 2 * c / es  # the half-space's centre displacement; a thin layer's is much smaller
    assert abs(u[n, n] - centre) < 3e-4 * scale  # the disc's area to 10 x 10 subsamples
    assert abs(u[n, n + int(round(c / s))] - edge) < 3e-3 * scale  # a pixelated rim


def test_kernel_on_a_half_space_matches_boussinesq_and_love():
    material, c, s = GelMaterial(2.0, 0.3, math.inf), 1.0, 0.04
    p, n = disc_pressure(c, s)
    u = LayerKernel(material, s).convolve(p)
    es = material.plane_strain_modulus
    assert u[n, n] == pytest.approx(2 * c / es, rel=3e-4)  # centre of a uniformly loaded disc
    assert u[n, n + 25] == pytest.approx(4 * c / (math.pi * es), rel=5e-3)  # its rim
    # one element: Love's square, u(0) = 8 c' asinh(1) / (pi E*) with half-side c'
    k = LayerKernel(material, 0.2)
    assert k.influence(1, 1)[0, 0] == pytest.approx(
        8 * 0.1 * math.asinh(1) / (math.pi * es), rel=1e-12
    )


# ----------------------------------------------------------------- contacts
@pytest.mark.parametrize("d", [0.1, 0.4])
def test_sphere_on_a_half_space_matches_hertz(d):
    material, R, s = GelMaterial(0.5, 0.5, math.inf), 10.0, 0.05
    res = paraboloid_contact(material, R, d, s)
    a_hertz = math.sqrt(R * d)
    f_hertz = 4 / 3 * material.plane_strain_modulus * math.sqrt(R) * d**1.5
    assert res.converged
    assert contact_radius(res, s) == pytest.approx(a_hertz, rel=0.02)
    assert res.force_n == pytest.approx(f_hertz, rel=0.02)
    # and the pressure is Hertz's: p0 = 2 E* a / (pi R) at the centre
    centre = res.pressure[res.pressure.shape[0] // 2, res.pressure.shape[1] // 2]
    assert centre == pytest.approx(
        2 * material.plane_strain_modulus * a_hertz / (math.pi * R), rel=0.02
    )


def test_sphere_on_a_thick_bonded_layer_follows_the_thickness_expansion():
    """To second order in a/h the layer only adds a uniform sink -gamma F / (pi E* h), gamma =
    -int (S - 1) dt, so d = (a^2/R)(1 - kappa a/h), kappa = 4 gamma / (3 pi), and F/F_Hertz =
    (1 - kappa a/h)^(-3/2). Its first-order term, 2 gamma / pi chi with chi = sqrt(R d)/h, is
    Dimitriadis et al. 2002's 1.133 chi for a bonded incompressible layer (their fitted alpha0(nu)
    gives 1.133, the exact integral 1.127)."""
    nu, R, d, s, chi = 0.5, 10.0, 0.25, 0.05, 0.1
    gamma = -quad(lambda t: float(layer_factor(t, nu)) - 1, 0, 40, limit=200)[0]
    assert 2 * gamma / math.pi == pytest.approx(1.133, rel=0.01)
    kappa = 4 * gamma / (3 * math.pi)
    h = math.sqrt(R * d) / chi
    material = GelMaterial(1.0, nu, h)
    res = paraboloid_contact(material, R, d, s, extent=1.0)
    eps = brentq(lambda e: e * math.sqrt(1 - kappa * e) - chi, 0, 1)  # a / h
    f_hertz = 4 / 3 * material.plane_strain_modulus * math.sqrt(R) * d**1.5
    assert res.force_n / f_hertz == pytest.approx((1 - kappa * eps) ** -1.5, rel=2e-3)
    assert contact_radius(res, s) == pytest.approx(eps * h, rel=0.01)


def test_thin_compressible_layer_reaches_the_winkler_limit():
    """a/h = 10, nu = 0.3: the layer acts as a Winkler foundation of constrained modulus M (Johnson,
    Contact Mechanics 1985): a = sqrt(2 R d), F = pi M R d^2 / h; corrections are O(h/a)."""
    nu, R, d = 0.3, 10.0, 0.1
    a_lim = math.sqrt(2 * R * d)
    h = a_lim / 10
    material = GelMaterial(1.0, nu, h)
    res = paraboloid_contact(material, R, d, h / 3)
    M = material.youngs_modulus_mpa * (1 - nu) / ((1 + nu) * (1 - 2 * nu))
    assert res.force_n == pytest.approx(math.pi * M * R * d * d / h, rel=0.01)
    assert contact_radius(res, h / 3) == pytest.approx(a_lim, rel=0.02)


def test_thin_incompressible_layer_converges_to_chadwick():
    """A thin bonded incompressible layer under a frictionless paraboloid (Chadwick, SIAM J. Appl.
    Math. 62, 2002): a = 2 sqrt(R d) (the displaced volume stays in the contact), F = 2 pi mu R^2 d^3
    / h^3. At a/h = 10 and 20 the contact radius still lags by O(h/a) and the force by O((h/a)^2);
    extrapolated to h/a -> 0 with those orders (Richardson) both land within 2 %."""
    nu, R, d = 0.5, 10.0, 0.1
    a_lim = 2 * math.sqrt(R * d)
    runs = []
    for ratio in (10, 20):
        h = a_lim / ratio
        material = GelMaterial(1.0, nu, h)
        res = paraboloid_contact(material, R, d, h / 3, extent=1.65)  # a_lim = 1.41 sqrt(2Rd)
        f_lim = 2 * math.pi * material.shear_modulus * R**2 * d**3 / h**3
        runs.append((contact_radius(res, h / 3) / a_lim, res.force_n / f_lim))
    (a10, f10), (a20, f20) = runs
    assert abs(a20 - 1) < abs(a10 - 1) and abs(f20 - 1) < abs(f10 - 1)
    assert 2 * a20 - a10 == pytest.approx(1.0, abs=0.02)
    assert (4 * f20 - f10) / 3 == pytest.approx(1.0, abs=0.02)


def test_a_flat_punch_wall_is_smoothed_as_an_elastic_half_space_smooths_it():
    """A rigid flat punch (vertical walls) of radius a pressed d into a half-space: F = 2 E* a d and
    outside u(r) = (2 d / pi) asin(a / r) (Boussinesq) — continuous at the wall, no step."""
    material, a, d, s = GelMaterial(0.5, 0.5, math.inf), 1.0, 0.1, 0.025
    n = int(2.2 * a / s)
    X, Y = square_grid(n, s)
    r = np.hypot(X, Y)
    punch = Flat(a)
    w = d - punch.gap(X, Y).astype(np.float64)  # -inf off the punch
    res = solve_contact(LayerKernel(material, s), w, tol=1e-6)
    assert res.force_n == pytest.approx(2 * material.plane_strain_modulus * a * d, rel=0.03)
    u, p = res.displacement, res.pressure
    outside = r >= a + 2 * s
    expected = 2 * d / math.pi * np.arcsin(np.minimum(a / r[outside], 1))
    assert np.abs(u[outside] - expected).max() < 0.02 * d
    # continuous: no neighbour step off the punch near the geometric wall's full depth d
    off = ~np.isfinite(w)
    steps = np.abs(np.diff(u, axis=1))[off[:, 1:] & off[:, :-1]]
    assert steps.max() < 0.2 * d
    # the contact conditions: p >= 0, p > 0 only where the gap closes, the gap never negative
    gap = u - w
    tol = 1e-6 * d
    assert p.min() >= 0 and np.all(np.abs(gap[p > 0]) <= tol)
    assert np.all(gap[np.isfinite(w)] >= -tol)
    assert abs(float(np.sum(p * np.where(np.isfinite(gap), gap, 0)))) < tol * p.sum()


# ----------------------------------------------------------------- a skin under tension
def test_a_skin_on_a_thin_layer_is_a_membrane_on_a_winkler_foundation():
    # a membrane of tension T on a foundation of stiffness M / h answers a point force F with
    # u(r) = F / (2 pi T) K0(r / l), l = sqrt(T h / M)
    from scipy.special import k0

    nu, h, T, s = 0.3, 0.01, 1.0, 0.005
    material = GelMaterial(1.0, nu, h, T)
    m = 1.0 * (1 - nu) / ((1 + nu) * (1 - 2 * nu))
    ell = math.sqrt(T * h / m)
    kernel = LayerKernel(material, s)
    table = kernel.influence(240, 240) / s**2  # per unit force
    lags = np.array([4, 8, 16, 24, 32, 48])
    r = lags * s
    expected = k0(r / ell) / (2 * math.pi * T)
    np.testing.assert_allclose(table[0, lags], expected, rtol=0.03)
    np.testing.assert_allclose(kernel.point(r), expected, rtol=0.03)


def test_a_skin_adds_its_tension_times_the_laplacian_to_the_layers_pressure():
    # u = K_T p  <=>  u = K (p + T lap(u)): the layer carries what the skin does not
    s, T = 0.1, 0.5
    bare = LayerKernel(GelMaterial(0.5, 0.5, 1.0), s)
    skin = LayerKernel(GelMaterial(0.5, 0.5, 1.0, T), s)
    X, Y = square_grid(100, s)
    p = np.exp(-(X**2 + Y**2) / (2 * 0.4**2))
    u = skin.convolve(p)
    lap = np.zeros_like(u)
    lap[1:-1, 1:-1] = (
        u[2:, 1:-1] + u[:-2, 1:-1] + u[1:-1, 2:] + u[1:-1, :-2] - 4 * u[1:-1, 1:-1]
    ) / s**2
    inner = (slice(50, 151), slice(50, 151))
    back = bare.convolve(p + T * lap)
    np.testing.assert_allclose(back[inner], u[inner], atol=1e-6 * np.abs(u).max())


def test_a_skin_shrinks_the_contact_and_spreads_the_dent():
    R, d, s = 2.35, 0.6, 0.1
    X, Y = square_grid(60, s)
    w = d - (X**2 + Y**2) / (2 * R)
    radii, far = [], []
    for T in (0.0, 0.5, 2.0):
        res = solve_contact(LayerKernel(GelMaterial(0.435, 0.5, 4.0, T), s), w, tol=1e-5)
        assert res.converged
        radii.append(contact_radius(res, s))
        far.append(res.displacement[60, 60 + 40] / d)  # 4 mm from the axis, past every contact
    assert radii[0] > radii[1] > radii[2]
    assert far[0] < far[1] < far[2]


def test_a_skin_needs_a_layer_and_a_tension_of_at_least_zero():
    for bad in (
        lambda: GelMaterial(1.0, 0.5, math.inf, 1.0),
        lambda: GelMaterial(1.0, 0.5, 4.0, -1),
    ):
        with pytest.raises(ConfigError, match="skin_tension"):
            bad()
    gel = {"youngs_modulus_mpa": 0.4, "poisson_ratio": 0.5, "thickness_mm": 4.0}
    assert GelMaterial.from_profile(gel).skin_tension_n_per_mm == 0.0
    assert GelMaterial.from_profile({**gel, "skin_tension_n_per_mm": 2}).skin_tension_n_per_mm == 2


def test_solver_edge_cases():
    k = LayerKernel(GelMaterial(0.5, 0.5, 4.0), 0.1)
    # no contact: nothing below the undeformed surface, or no surface at all
    for w in (np.full((9, 9), -0.1), np.full((9, 9), -np.inf), np.full((9, 9), np.nan)):
        res = solve_contact(k, w)
        assert res.force_n == 0 and not res.contact.any() and not res.displacement.any()
    zero = solve_contact(k, np.zeros((9, 9)))  # depth 0: touching, not pressing
    assert zero.force_n == 0
    with pytest.raises(ConfigError, match=r"\+inf"):
        solve_contact(k, np.full((5, 5), np.inf))
    with pytest.raises(ConfigError, match="2-D"):
        solve_contact(k, np.zeros(5))
    # NaN holes are "no surface": the contact avoids them
    w = 0.1 - np.hypot(*square_grid(10, 0.1)) ** 2 / 4
    w[8:13, 8:13] = np.nan
    res = solve_contact(k, w)
    assert res.converged and not res.contact[8:13, 8:13].any() and res.force_n > 0
    for bad in (
        lambda: GelMaterial(0, 0.5, 4.0),
        lambda: GelMaterial(1.0, 0.6, 4.0),
        lambda: GelMaterial(1.0, 0.5, 0.0),
        lambda: LayerKernel(GelMaterial(1.0, 0.5), 0.0),
    ):
        with pytest.raises(ConfigError):
            bad()


# ----------------------------------------------------------------- the renderer
def elastic_profile(name: str, **gel) -> dict:
    profile = copy.deepcopy(load_profile("sensor", name))
    profile["gel"].update(mechanics="elastic", **gel)
    return profile


@functools.cache
def elastic_sim(name: str) -> GelSimulator:
    return GelSimulator(elastic_profile(name), seed=7)


@pytest.fixture(params=["digit", "gelsight_mini"])
def esim(request):
    return elastic_sim(request.param)


def test_profiles_keep_the_geometric_gel_and_carry_the_elastic_constants():
    for name in ("digit", "gelsight_mini"):
        gel = load_profile("sensor", name)["gel"]
        assert gel["mechanics"] == "geometric"
        assert 0.1 <= gel["youngs_modulus_mpa"] <= 1.0 and gel["poisson_ratio"] == 0.5


def test_a_scenes_bench_picks_the_simulated_gels_mechanics():
    """`bench.gel_mechanics` overrides the profile's for the bench alone: the frames change, the
    profile the rest of the study reads does not."""
    from threedcal.sim.bench import SimBench
    from threedcal.study.config import validate_config

    sensor = load_profile("sensor", "gelsight_mini")
    frames = {}
    for mechanics in ("geometric", "elastic", None):
        scene = {"sensor": "gelsight_mini", "printer": "ender3"}
        if mechanics:
            scene["bench"] = {"gel_mechanics": mechanics}
        scene = validate_config({"seed": 1, "scenes": {"s": scene}})["scenes"]["s"]
        with SimBench(sensor, 2.0, scene["bench"], scene["seed"]) as bench:
            assert bench.gel.inner.mechanics == (mechanics or "geometric")  # behind the lens
            centre = (sensor["image"]["width_px"] / 2, sensor["image"]["height_px"] / 2)
            frames[mechanics] = bench.gel.render(Sphere(2.0), centre, 0.0, 0.5, frame_index=1)
    assert sensor["gel"]["mechanics"] == "geometric"
    np.testing.assert_array_equal(frames[None], frames["geometric"])
    assert np.abs(frames["elastic"].astype(int) - frames["geometric"]).max() > 20
    with pytest.raises(ConfigError, match="gel_mechanics"):
        validate_config({"scenes": {"s": {"sensor": "digit", "bench": {"gel_mechanics": "soft"}}}})


def test_elastic_gel_needs_its_constants(tmp_path):
    profile = elastic_profile("gelsight_mini")
    del profile["gel"]["youngs_modulus_mpa"]
    with pytest.raises(ConfigError, match="gel.youngs_modulus_mpa"):
        GelSimulator(profile)
    bad = elastic_profile("gelsight_mini")
    bad["gel"]["mechanics"] = "rubbery"
    with pytest.raises(ConfigError, match="rubbery"):
        GelSimulator(bad)


def test_elastic_ball_renders_deterministically_and_touches_less_than_the_geometry(esim):
    ball, d = Sphere(2.0), 1.0
    c = (esim.width / 2 + 0.3, esim.height / 2 - 0.4)
    a = esim.render(ball, c, 0, d, frame_index=3, hold_frame=2)
    # the same bytes from a fresh simulator, and after other presses (no state carried over)
    fresh = GelSimulator(esim.profile, seed=7)
    b = fresh.render(ball, c, 0, d, frame_index=3, hold_frame=2)
    fresh.render(Sphere(1.0), (30.5, 40.2), 0, 0.7, frame_index=1)
    fresh.render(ball, c, 0, d, frame_index=3, hold_frame=1)
    assert a.dtype == np.uint8 and np.array_equal(a, b)
    assert np.array_equal(a, fresh.render(ball, c, 0, d, frame_index=3, hold_frame=2))
    press = esim.press(ball, c, 0, d)
    s = esim._elastic.spacing_mm
    radius = contact_radius(press.result, s)
    # a bare layer: between a half-space's sqrt(R d) (softer) and the rigid intersection
    # sqrt(2 R d - d^2); a skin (the Mini's) draws the contact in below the bare layer's
    assert radius < math.sqrt(2 * 2.0 * d - d * d)
    if esim.profile["gel"].get("skin_tension_n_per_mm", 0) == 0:
        assert math.sqrt(2.0 * d) < radius
    else:
        bare = GelSimulator(elastic_profile(esim.profile["name"], skin_tension_n_per_mm=0), seed=7)
        assert radius < 0.9 * contact_radius(bare.press(ball, c, 0, d).result, s)
    win = esim.window(ball, c, d)
    z, contact = esim.surface(ball, c, 0, d, win)
    assert contact.any() and np.isfinite(z).all()


def test_on_the_domed_digit_the_elastic_contact_sits_toward_the_apex():
    """A ball pressed into a sloping gel touches first where the gap is smallest: for a paraboloid
    of radius R on a dome z = k x², at x0 - 2 k x0 R / (1 + 2 k R) from the apex. The elastic gel
    has that shift to within 15 % (86 % of it here: a sphere, not a paraboloid, on a layer, not a
    half-space), up to ~4 px at the DIGIT's sides, which registration must allow for before the
    DIGIT can default to it (docs/explanation/simulator.md, With registration presses and the lens)."""
    sim = elastic_sim("digit")
    dome = sim.profile["gel"]["dome"]
    ball, radius, depth = Sphere(2.0), 2.0, 0.4
    s = sim.px_per_mm
    for x_mm, y_mm in ((5.0, 0.0), (-4.0, 0.0), (0.0, 6.0)):
        centre = (
            sim._cx + (x_mm + dome["apex_x_mm"]) * s,
            sim._cy + (y_mm + dome["apex_y_mm"]) * s,
        )
        press = sim.press(ball, centre, 0, depth)
        X, Y = press.node_coords(press.node_box())
        touched = press.result.contact
        found = np.array([X[touched].mean(), Y[touched].mean()])
        axis = np.array(sim.axis_mm(centre))
        expected = np.array(
            [
                -2 * k * offset * radius / (1 + 2 * k * radius)
                for k, offset in ((dome["kx_per_mm"], x_mm), (dome["ky_per_mm"], y_mm))
            ]
        )
        assert np.abs(expected).max() * s > 1.0  # over a pixel: a shift registration would see
        np.testing.assert_allclose(
            found - axis, expected, atol=0.15 * np.abs(expected).max() + 0.01
        )


def test_the_gel_never_goes_through_the_indenter_and_equals_it_in_contact(esim):
    """A cylinder (vertical walls) and a ball on both gels (DIGIT: domed, so depth is measured from
    the undeformed dome under the axis)."""
    cyl = Relief(np.where(np.hypot(*square_grid(30, 1 / 20)) <= 1.2, 0.0, np.nan), 20.0)
    for indenter, d in ((Sphere(2.0), 1.2), (cyl, 0.6)):
        c = (esim.width * 0.35, esim.height * 0.6)
        win = esim.window(indenter, c, d)
        z, contact = esim.surface(indenter, c, 0, d, win)
        y0, y1, x0, x1 = win
        w = esim.interference(indenter, c, 0, d)(esim.X[y0:y1, x0:x1], esim.Y[y0:y1, x0:x1])
        depth_in = z - esim.Z0[y0:y1, x0:x1]  # how far the gel sank
        has = np.isfinite(w)
        assert np.all(depth_in[has] >= w[has] - 1e-5)  # never through the indenter
        # the indenter in contact, to the solver's tolerance (1e-4 of the depth) and the
        # interpolation's
        assert np.abs(depth_in[contact] - w[contact]).max() < 3e-4 * d + 5e-4
        # the indenter's deepest point (d under the axis; a flat end on the dome's slope goes deeper)
        assert depth_in.max() == pytest.approx(np.nanmax(w), abs=0.01 * d)
        # smooth off the indenter: the wall's foot has a finite slope, not the wall's step
        step = np.abs(np.diff(depth_in, axis=1))[~has[:, 1:] & ~has[:, :-1]]
        assert step.max() < 0.25 * d


def test_a_press_at_the_frame_edge_is_the_same_gel_seen_partly():
    """The solve is not clipped to the frame: a ball centred on the corner pixel deforms the gel as
    the same ball does in mid-frame (flat gel, translation by whole lattice steps)."""
    sim = elastic_sim("gelsight_mini")
    ball, d = Sphere(2.0), 0.8
    corner, mid = (0.0, 0.0), (100.0, 80.0)
    zc, _ = sim.surface(ball, corner, 0, d, (0, 40, 0, 40))
    zm, _ = sim.surface(ball, mid, 0, d, (80, 120, 100, 140))
    np.testing.assert_allclose(zc, zm, atol=2e-4 * d)
    frame = sim.render(ball, corner, 0, d, frame_index=1)
    assert not np.array_equal(frame, sim.blank(1))


def test_no_contact_and_zero_depth_leave_the_frame_blank(esim):
    ball = Sphere(2.0)
    far = (-10 * esim.width, 5 * esim.height)
    assert np.array_equal(esim.render(ball, far, 0, 1.0, frame_index=4), esim.blank(4))
    assert np.array_equal(esim.render(ball, (50, 50), 0, 0.0, frame_index=4), esim.blank(4))
    # depth is measured from the undeformed surface under the axis: at 0 at the apex nothing presses
    assert esim.press(ball, ((esim.width - 1) / 2, (esim.height - 1) / 2), 0, 0.0) is None


@pytest.mark.parametrize("indenter", [Flat(3.0), Sphere(1.0)])
def test_elastic_walls_at_full_depth_stay_finite(esim, indenter):
    c = (esim.width / 2, esim.height / 2)
    change = esim.contact_change(indenter, c, 0, esim.max_penetration_mm)
    assert np.isfinite(change[1]).all()
    assert esim.render(indenter, c, 0, esim.max_penetration_mm).dtype == np.uint8


def test_far_field_first_order_shading_matches_full_shading(esim, monkeypatch):
    """The gentle far field is shaded to first order in its slope and height; against shading every
    pixel in full the image moves by well under the 8-bit step."""
    c = (esim.width * 0.4, esim.height * 0.45)
    for indenter, d in ((Sphere(2.0), 1.5), (Flat(2.0), 1.0)):
        win = esim.window(indenter, c, d)
        z, _ = esim.surface(indenter, c, 0, d, win)
        linear = esim._elastic_change(z, win, c)
        monkeypatch.setattr(elastic_render, "LINEAR_SLOPE", 0.0)
        full = esim._elastic_change(z, win, c)
        monkeypatch.undo()
        assert np.abs(linear - full).max() < 0.05


def test_pixels_off_the_lattice_sample_the_same_gel(monkeypatch):
    """The lens hook: a cubic spline at each pixel's gel point (pixels off the lattice) gives the gel
    the separable lattice interpolation gives (two cubic interpolants of the same nodes)."""
    sim = elastic_sim("gelsight_mini")
    ball, c, d = Sphere(2.0), (150.3, 110.6), 1.0
    win = sim.window(ball, c, d)
    on_lattice, contact = sim.surface(ball, c, 0, d, win)
    monkeypatch.setattr(sim, "_pixel_lattice", None)
    remapped, contact2 = sim.surface(ball, c, 0, d, win)
    assert np.abs(remapped - on_lattice).max() < 2e-3 * d
    assert (contact != contact2).sum() <= 0.05 * contact.sum()


def test_a_test_object_presses_the_elastic_gel():
    """The pawn (a mesh turned into a relief, vertical walls) on the elastic Mini: it renders, the
    gel never goes through it and equals it in contact, and its walls leave no step."""
    from threedcal.evaluate.object_presses import relief_indenter
    from threedcal.evaluate.objects import load_object

    sim = elastic_sim("gelsight_mini")
    pawn = relief_indenter(load_object("pawn"), sim.px_per_mm, 7.0)
    c, d = (170.2, 115.7), 0.8
    win = sim.window(pawn, c, d)
    z, contact = sim.surface(pawn, c, 0, d, win)
    y0, y1, x0, x1 = win
    w = sim.interference(pawn, c, 0, d)(sim.X[y0:y1, x0:x1], sim.Y[y0:y1, x0:x1])
    sunk = z - sim.Z0[y0:y1, x0:x1]
    has = np.isfinite(w)
    assert contact.any() and np.all(sunk[has] >= w[has] - 1e-5)
    assert np.abs(sunk[contact] - w[contact]).max() < 3e-4 * d + 5e-4
    assert np.abs(np.diff(sunk, axis=1))[~has[:, 1:] & ~has[:, :-1]].max() < 0.25 * d
    assert sim.press(pawn, c, 0, d).force_n > 0
    frame = sim.render(pawn, c, 0, d, frame_index=2)
    assert frame.dtype == np.uint8 and not np.array_equal(frame, sim.blank(2))
