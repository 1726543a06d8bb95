"""The elastic gel (threedcal.sim.elastic) measured: its checks, its contact, its label error, and
what registration makes of it (the simulator's gel-mechanics explanation):

    .venv/bin/python -m diagnostics.elastic_gel derive        # the layer compliance, by sympy
    .venv/bin/python -m diagnostics.elastic_gel checks        # elastic_checks.png
    .venv/bin/python -m diagnostics.elastic_gel contact       # elastic_contact.png
    .venv/bin/python -m diagnostics.elastic_gel locators      # contact locators on a grid of poses
    .venv/bin/python -m diagnostics.elastic_gel registration  # the collection bench, both gels

Figures go to `--out` (default docs/figures). No step names: every step (a few minutes on 2
cores). `contact` also prints the label error (gel surface against the rigid ball the labels
describe). The sensors are the built-in profiles with gel.mechanics set to elastic (everything else
as built). `--smoke`: coarse grids and few depths, seconds (the figures are then not the docs').
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml
from scipy.integrate import quad
from scipy.optimize import brentq

from threedcal.dataset.labels import sphere_depth, sphere_gradients
from threedcal.profiles import load_profile
from threedcal.sim.elastic import solve_contact
from threedcal.sim.indenters import Sphere
from threedcal.sim.layer_kernel import GelMaterial, LayerKernel, layer_factor
from threedcal.sim.optics import GelSimulator

FIGURES = Path(__file__).resolve().parents[1] / "docs" / "figures"
BALL_MM = 2.0  # the study's probe (config.yaml: probe.radius_mm)


@dataclass(frozen=True)
class Sizes:
    """How fine and how many: the docs' figures, or a smoke run's seconds."""

    grid_mm: float = 0.05  # the checks' node spacing (paraboloid R = 10 mm)
    hertz_depths: tuple = (0.05, 0.1, 0.2, 0.3, 0.4, 0.5)
    chis: tuple = (0.05, 0.1, 0.2, 0.3, 0.4)
    thin_ratios: tuple = (5, 10, 20)
    contact_grid_px: int = 1  # every pixel a node
    contact_depths: tuple = (0.25, 0.5, 0.75, 1.0, 1.25, 1.5, 2.0)
    label_depths: tuple = (0.5, 1.0, 1.5)
    locator_grid: tuple = (5, 4)  # columns x rows of known centres
    registration_spacing_mm: float = 2.0


FULL = Sizes()
SMOKE = Sizes(
    grid_mm=0.2,
    hertz_depths=(0.2, 0.4),
    chis=(0.1, 0.3),
    thin_ratios=(5, 10),
    contact_grid_px=4,
    contact_depths=(0.5, 1.0),
    label_depths=(1.0,),
    locator_grid=(3, 2),
    registration_spacing_mm=4.0,
)


def elastic(name: str, **gel) -> dict:
    profile = copy.deepcopy(load_profile("sensor", name))
    profile["gel"].update(mechanics="elastic", **gel)
    return profile


def paraboloid(material, R, d, s, extent):
    n = int(math.ceil(extent / s))
    ax = np.arange(-n, n + 1) * s
    X, Y = np.meshgrid(ax, ax)
    res = solve_contact(LayerKernel(material, s), d - (X**2 + Y**2) / (2 * R), tol=1e-6)
    return res, math.sqrt(res.contact.sum() * s * s / math.pi)


def derive(sizes: Sizes = FULL, out: Path = FIGURES) -> dict:
    """The surface compliance of a layer bonded to a rigid base, from the Navier equations of one
    plane-strain Fourier mode (u_x = U(z) sin kx, u_z = W(z) cos kx; z into the gel, the surface at
    z = 0 loaded by p cos kx, shear-free; the base z = h fixed), against sim.layer_kernel.layer_factor."""
    import sympy as sp

    z, k, h, mu, nu, p, X = sp.symbols("z k h mu nu p X", positive=True)
    lam = 2 * mu * nu / (1 - 2 * nu)
    A, B = sp.symbols("A1:5"), sp.symbols("B1:5")
    U = (A[0] + A[1] * z) * sp.exp(k * z) + (A[2] + A[3] * z) * sp.exp(-k * z)
    W = (B[0] + B[1] * z) * sp.exp(k * z) + (B[2] + B[3] * z) * sp.exp(-k * z)
    navier = [
        -(lam + 2 * mu) * k**2 * U + mu * U.diff(z, 2) - (lam + mu) * k * W.diff(z),
        (lam + 2 * mu) * W.diff(z, 2) - mu * k**2 * W + (lam + mu) * k * U.diff(z),
    ]
    eqs = []
    for e in navier:  # every coefficient of z^i exp(+-kz) vanishes
        e = e.subs({sp.exp(k * z): X, sp.exp(-k * z): 1 / X}) * X
        eqs += sp.Poly(sp.expand(sp.numer(sp.together(e))), X, z).coeffs()
    W = W.subs(sp.solve(eqs, B, dict=True)[0])
    szz = lam * (k * U + W.diff(z)) + 2 * mu * W.diff(z)
    sxz = mu * (U.diff(z) - k * W)
    bcs = [szz.subs(z, 0) + p, sxz.subs(z, 0), U.subs(z, h), W.subs(z, h)]
    unknowns = [c for c in (*A, *B) if W.has(c) or U.has(c)]
    w0 = W.subs(z, 0).subs(sp.solve(bcs, unknowns, dict=True)[0])
    S = sp.simplify(w0 / ((1 - nu) * p / (mu * k)))  # over the half-space's 2 / (E* k)
    print("S(kh) =", S)
    f = sp.lambdify((k, h, nu), S)
    worst = max(
        abs(float(f(t, 1.0, v)) - float(layer_factor(t, v)))
        for t in (0.01, 0.1, 0.5, 1.0, 3.0, 10.0)
        for v in (0.0, 0.3, 0.49, 0.5)
    )
    print(f"largest difference from threedcal.sim.layer_kernel.layer_factor: {worst:.1e}")
    return {"layer_factor_difference": worst}


def checks(sizes: Sizes = FULL, out: Path = FIGURES) -> dict:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
    R, s = 10.0, sizes.grid_mm  # a paraboloid of R = 10 mm on a grid of 0.05 mm
    found = hertz_check(axes[0], R, s, sizes.hertz_depths)
    found.update(bonded_layer_check(axes[1], R, s, sizes.chis))
    found.update(thin_layer_check(axes[2], R, sizes.thin_ratios))
    fig.tight_layout()
    out.mkdir(parents=True, exist_ok=True)
    fig.savefig(out / "elastic_checks.png", dpi=110)
    plt.close(fig)
    print(f"wrote {out / 'elastic_checks.png'}")
    return found


def hertz_check(ax, R: float, s: float, depths) -> dict:
    """1. Hertz: a paraboloid on a half-space."""
    m = GelMaterial(1.0, 0.5, math.inf)
    depths = np.array(depths)
    rows = [paraboloid(m, R, d, s, 1.15 * math.sqrt(2 * R * d)) for d in depths]
    a_err = [a / math.sqrt(R * d) - 1 for (_, a), d in zip(rows, depths, strict=True)]
    f_err = [
        r.force_n / (4 / 3 * m.plane_strain_modulus * math.sqrt(R) * d**1.5) - 1
        for (r, _), d in zip(rows, depths, strict=True)
    ]
    print("Hertz (paraboloid R = 10 mm on a half-space, grid 0.05 mm):")
    for d, ea, ef in zip(depths, a_err, f_err, strict=True):
        print(f"  d = {d:.2f} mm: contact radius {100 * ea:+.2f} %, force {100 * ef:+.3f} %")
    ax.plot(depths, 100 * np.array(a_err), "o-", label="contact radius a")
    ax.plot(depths, 100 * np.array(f_err), "s-", label="force F")
    ax.axhspan(-2, 2, color="0.9", label="±2 % (test)")
    ax.set(xlabel="depth d (mm)", ylabel="BEM − Hertz (%)", title="Sphere on a half-space")
    ax.legend()
    return {"hertz_radius_error": a_err, "hertz_force_error": f_err}


def bonded_layer_check(ax, R: float, s: float, chis) -> dict:
    """2. a thick bonded incompressible layer: F / F_Hertz against chi = sqrt(R d) / h."""
    nu, d = 0.5, 0.25
    gamma = -quad(lambda t: float(layer_factor(t, nu)) - 1, 0, 40, limit=200)[0]
    kappa = 4 * gamma / (3 * math.pi)
    chis = np.array(chis)
    bem, closed = [], []
    for chi in chis:
        h = math.sqrt(R * d) / chi
        mat = GelMaterial(1.0, nu, h)
        res, _ = paraboloid(mat, R, d, s, 1.3 * math.sqrt(R * d) * (1 + chi))
        bem.append(res.force_n / (4 / 3 * mat.plane_strain_modulus * math.sqrt(R) * d**1.5))
        eps = brentq(lambda e, c=chi: e * math.sqrt(1 - kappa * e) - c, 0, 2 / (3 * kappa))
        closed.append((1 - kappa * eps) ** -1.5)
    dimitriadis = 1 + 1.133 * chis + 1.283 * chis**2 + 0.769 * chis**3 + 0.0975 * chis**4
    print(
        f"bonded incompressible layer: gamma = {gamma:.4f}, 2 gamma / pi = {2 * gamma / math.pi:.4f}"
    )
    for c, b, e, dm in zip(chis, bem, closed, dimitriadis, strict=True):
        print(
            f"  chi = {c:.2f}: F/F_H BEM {b:.4f}, second-order closed form {e:.4f} "
            f"({100 * (b / e - 1):+.2f} %), Dimitriadis 2002 {dm:.4f} ({100 * (b / dm - 1):+.2f} %)"
        )
    ax.plot(chis, bem, "o-", label="BEM")
    ax.plot(chis, closed, "--", label="(1 − κ a/h)^−3/2 (2nd order)")
    ax.plot(chis, dimitriadis, ":", label="Dimitriadis et al. 2002")
    ax.set(
        xlabel="χ = sqrt(R d) / h", ylabel="F / F_Hertz", title="Sphere on a bonded layer, ν = 0.5"
    )
    ax.legend()
    return {"bonded_force_ratio": bem, "bonded_closed_form": closed}


def thin_layer_check(ax, R: float, ratios) -> dict:
    """3. thin layers: the Winkler (nu = 0.3) and Chadwick (nu = 0.5) limits."""
    d = 0.1
    ratios = np.array(ratios)
    found = {}
    for nu, a_lim, style in ((0.3, math.sqrt(2 * R * d), "o-"), (0.5, 2 * math.sqrt(R * d), "s-")):
        fs, as_ = [], []
        for ratio in ratios:
            h = a_lim / ratio
            mat = GelMaterial(1.0, nu, h)
            res, a = paraboloid(mat, R, d, h / 3, 1.15 * a_lim)
            if nu < 0.5:
                M = mat.youngs_modulus_mpa * (1 - nu) / ((1 + nu) * (1 - 2 * nu))
                f_lim = math.pi * M * R * d * d / h
            else:
                f_lim = 2 * math.pi * mat.shear_modulus * R**2 * d**3 / h**3
            fs.append(res.force_n / f_lim)
            as_.append(a / a_lim)
        name = "Winkler (Johnson 1985)" if nu < 0.5 else "Chadwick 2002"
        print(f"thin layer, nu = {nu} against {name}:")
        for r, f, a in zip(ratios, fs, as_, strict=True):
            print(f"  a/h = {r}: F / F_lim {f:.4f}, a / a_lim {a:.4f}")
        found[f"thin_force_ratio_nu{nu}"] = fs
        if nu == 0.5 and len(ratios) > 2:
            print(
                f"  Richardson (a: O(h/a), F: O((h/a)^2)) from a/h = 10, 20: a {2 * as_[2] - as_[1]:.4f},"
                f" F {(4 * fs[2] - fs[1]) / 3:.4f}"
            )
        ax.plot(1 / ratios, fs, style, label=f"F / F_lim, ν = {nu}")
        ax.plot(1 / ratios, as_, style, mfc="none", label=f"a / a_lim, ν = {nu}")
    ax.axhline(1, color="0.5", lw=0.8)
    ax.set(xlabel="h / a", ylabel="BEM / thin-layer limit", title="Thin bonded layers")
    ax.legend(fontsize=8)
    return found


def contact(sizes: Sizes = FULL, out: Path = FIGURES) -> dict:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ball = Sphere(BALL_MM)
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
    depths = np.array(sizes.contact_depths)
    found = {}
    for k, name in enumerate(("digit", "gelsight_mini")):
        sim = GelSimulator(elastic(name, elastic_grid_px=sizes.contact_grid_px), seed=0)
        c = ((sim.width - 1) / 2, (sim.height - 1) / 2)
        radii, forces = [], []
        for d in depths:
            press = sim.press(ball, c, 0.0, float(d))
            s = press.spacing_mm
            radii.append(math.sqrt(press.result.contact.sum() * s * s / math.pi))
            forces.append(press.force_n)
        geometric = np.sqrt(2 * BALL_MM * depths - depths**2)
        table = [
            f"  d = {d:.2f} mm: elastic a = {a:.3f} mm, geometric {g:.3f} mm (ratio {a / g:.3f}), "
            f"half-space Hertz {math.sqrt(BALL_MM * d):.3f} mm, F = {f:.2f} N"
            for d, a, g, f in zip(depths, radii, geometric, forces, strict=True)
        ]
        gel = sim.profile["gel"]
        print(
            f"{name} (h = {gel['thickness_mm']} mm, nu = {gel['poisson_ratio']}), ball {BALL_MM} mm:"
        )
        print("\n".join(table))
        found[name] = {"contact_radius_mm": radii, "geometric_mm": list(geometric)}
        found[name]["force_n"] = forces
        ax = axes[0]
        ax.plot(depths, radii, "o-", label=f"{name}: elastic")
        if k == 0:
            ax.plot(depths, geometric, "k--", label="geometric sqrt(2Rd − d²)")
            ax.plot(depths, np.sqrt(BALL_MM * depths), "k:", label="half-space Hertz sqrt(Rd)")
        # label error: the gel against the rigid ball, at the frame centre, by radius
        ax2 = axes[1 + k]
        print(f"  label error (gel - rigid ball), {name}:")
        for d in sizes.label_depths:
            win = (0, sim.height, 0, sim.width)
            z, _ = sim.surface(ball, c, 0.0, d, win)
            gel = (z - sim.Z0).astype(np.float64)  # sunk below the undeformed surface, mm
            label = sphere_depth(z.shape, c, BALL_MM, d, sim.px_per_mm)
            grad = sphere_gradients(z.shape, c, BALL_MM, d, sim.px_per_mm)
            gy, gx = np.gradient(gel, 1 / sim.px_per_mm)
            dz = (gel - label) * 1000
            dg = np.hypot(gx - grad[..., 0], gy - grad[..., 1])
            yy, xx = np.mgrid[: z.shape[0], : z.shape[1]]
            r = np.hypot(xx - c[0], yy - c[1]) / sim.px_per_mm
            a_geo = math.sqrt(2 * BALL_MM * d - d * d)
            ring = r < a_geo + 1.0
            worst = np.unravel_index(np.argmax(np.abs(dz) * ring), dz.shape)
            print(
                f"    d = {d:.1f} mm: largest height error {dz[worst]:+.0f} um at r = "
                f"{r[worst]:.2f} mm (rim at {a_geo:.2f}); largest slope error "
                f"{dg[ring].max():.2f} at r = {r[ring][np.argmax(dg[ring])]:.2f} mm; "
                f"beyond the rim the gel sits {dz[(r > a_geo) & ring].max():.0f} um below the "
                f"label (0), the pile-up rises {-gel.min() * 1000:.0f} um"
            )
            row = int(round(c[1]))
            cols = np.arange(z.shape[1])
            rr = (cols - c[0]) / sim.px_per_mm
            ax2.plot(rr, gel[row] * 1000, label=f"gel, d = {d}")
            ax2.plot(rr, label[row] * 1000, "k--", lw=0.8)
        ax2.set(
            xlabel="x from the ball axis (mm)",
            ylabel="depth into the gel (µm)",
            title=f"{name}: elastic gel (solid) vs label (dashed)",
            xlim=(-4, 4),
        )
        ax2.legend(fontsize=8)
    axes[0].set(xlabel="depth d (mm)", ylabel="contact radius (mm)", title=f"Ball R = {BALL_MM} mm")
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    out.mkdir(parents=True, exist_ok=True)
    fig.savefig(out / "elastic_contact.png", dpi=110)
    plt.close(fig)
    print(f"wrote {out / 'elastic_contact.png'}")
    return found


def locators(sizes: Sizes = FULL, out: Path = FIGURES) -> dict:
    """The dataset stage's contact locators (rim, mirror symmetry) on Mini frames of a ball 1 mm deep
    at 20 known sub-pixel centres (5 columns x 4 rows), each gel: error found - true, px."""
    columns, rows = sizes.locator_grid
    measured = {}
    from threedcal.dataset.contacts import locate_contact
    from threedcal.dataset.symmetry import refine_by_symmetry

    for mechanics in ("geometric", "elastic"):
        profile = copy.deepcopy(load_profile("sensor", "gelsight_mini"))
        profile["gel"]["mechanics"] = mechanics
        sim = GelSimulator(profile, seed=1)
        blank = np.mean([sim.blank(i).astype(np.float32) for i in range(10)], axis=0)
        rng = np.random.default_rng(0)
        truth, frames = [], []
        for cx in np.linspace(60, sim.width - 61, columns):
            for cy in np.linspace(60, sim.height - 61, rows):
                x, y = cx + rng.uniform(-1, 1), cy + rng.uniform(-1, 1)
                shots = [
                    sim.render(Sphere(BALL_MM), (x, y), 0, 1.0, frame_index=k) for k in range(2)
                ]
                mean = np.mean(np.asarray(shots, np.float32), axis=0)
                frames.append(np.clip(mean + 0.5, 0, 255).astype(np.uint8))
                truth.append((x, y))
        rim = [locate_contact(f, blank) for f in frames]
        symmetric = refine_by_symmetry(frames, blank, rim).contacts
        for name, found in (("rim", rim), ("symmetry", symmetric)):
            pairs = [(t, c) for t, c in zip(truth, found, strict=True) if c is not None]
            measured[f"{mechanics}_{name}_found"] = len(pairs)
            if not pairs:
                print(f"{mechanics:9s} {name:8s}: no contact found of {len(truth)}")
                continue
            err = np.array([(c.x_px - x, c.y_px - y) for (x, y), c in pairs])
            size = np.hypot(err[:, 0], err[:, 1])
            measured[f"{mechanics}_{name}_rms_px"] = float(np.sqrt(np.mean(size**2)))
            column = np.array([x for (x, _), _ in pairs]) < 80  # the column 60 px from the left
            print(
                f"{mechanics:9s} {name:8s}: rms {np.sqrt(np.mean(size**2)):.2f} px; 60 px from the "
                f"left edge {_mean(size[column]):.2f} px, elsewhere {_mean(size[~column]):.2f} px "
                f"(mean); {len(truth) - len(pairs)} of {len(truth)} contacts not found"
            )
    return measured


def _mean(values: np.ndarray) -> float:
    return float(values.mean()) if values.size else float("nan")


def registration(sizes: Sizes = FULL, out: Path = FIGURES) -> dict:
    """tests/collect/test_collect_bench.py's two registration set-ups, with each gel."""
    from threedcal.dataset.build import build_collected
    from threedcal.study.config import validate_config
    from threedcal.study.scene import dataset_settings
    from threedcal.study.session import collect_scene

    setups = {
        "gelsight_mini, 1 mm, seating 0.5 mm / 2 deg, touch +0.1 mm": (
            2,
            "gelsight_mini",
            {"spacing_mm": sizes.registration_spacing_mm, "depth_mm": 1.0, "frames": 1},
            {"seating_offset_mm": 0.5, "seating_rotation_deg": 2.0, "touch_offset_mm": 0.1},
        ),
        "digit, 0.5/1.0/1.5 mm, touch +0.1 mm": (
            3,
            "digit",
            {
                "spacing_mm": sizes.registration_spacing_mm,
                "depths_mm": [0.5, 1.0, 1.5],
                "frames": 1,
            },
            {"touch_offset_mm": 0.1},
        ),
    }
    measured = {}
    for title, (seed, name, plan, bench) in setups.items():
        for mechanics in ("geometric", "elastic"):
            with tempfile.TemporaryDirectory() as tmp:
                tmp = Path(tmp)
                profile = copy.deepcopy(load_profile("sensor", name))
                profile["gel"]["mechanics"] = mechanics
                for key in ("source",):
                    profile.pop(key, None)
                (tmp / f"{name}.yaml").write_text(yaml.safe_dump(profile))
                scene = validate_config(
                    {
                        "seed": seed,
                        "scenes": {
                            "s": {
                                "sensor": str(tmp / f"{name}.yaml"),
                                "printer": "ender3",
                                "plan": plan,
                                "bench": bench,
                            }
                        },
                    }
                )["scenes"]["s"]
                collect_scene(
                    "s", scene, tmp / "raw.zarr", truth_path=tmp / "truth.json", progress=False
                )
                paths = [tmp / n for n in ("ts", "splits.csv", "reg.json", "reg.png", "truth.json")]
                record = build_collected(
                    dataset_settings(scene), tmp / "raw.zarr", *paths, progress=False
                )
                truth = json.loads((tmp / "truth.json").read_text())
            measured[f"{name}_{mechanics}_error_px"] = float(record["error_px"])
            rot = record.get("rotation_deg", math.nan) - truth.get("seating_rotation_deg", 0.0)
            print(
                f"{title} [{mechanics}]: registration error {record['error_px']:.3f} px "
                f"(affine residual {record['residual_px']:.3f} px, locator {record['locator']}), "
                f"rotation error {rot:+.3f} deg, touch-height error "
                f"{record['touch_offset_error_mm']:+.3f} mm"
                + (
                    f", rim edge offset {record['rim_edge_offset_mm']:+.3f} mm"
                    if record.get("rim_edge_offset_mm") is not None
                    else ""
                ),
                flush=True,
            )
    return measured


STEPS = {"derive": derive, "checks": checks, "contact": contact}
STEPS.update(locators=locators, registration=registration)


def main(argv: list[str] | None = None) -> dict:
    """Run the steps named (every step when none); {step: what it measured}."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("steps", nargs="*", choices=[*STEPS, "all"], default=["all"])
    parser.add_argument("--out", type=Path, help="folder for the figures (docs/figures)")
    parser.add_argument("--smoke", action="store_true", help="coarse and few: seconds")
    args = parser.parse_args(argv)
    sizes = SMOKE if args.smoke else FULL
    # a smoke run never overwrites the docs' figures
    out = args.out or (Path(tempfile.mkdtemp(prefix="elastic_gel-")) if args.smoke else FIGURES)
    chosen = list(STEPS) if "all" in args.steps else args.steps
    return {name: STEPS[name](sizes, out) for name in chosen}


if __name__ == "__main__":
    main()
