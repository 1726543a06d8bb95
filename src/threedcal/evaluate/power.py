"""Power of the ablation's design, by simulation from a study's own validation errors.

How many replicates and validation points does the paired test need to detect a change of mean
validation MSE as large as the equivalence margin, and the TOST to show equivalence when there is no
change? The per-coordinate MSE of fraction P, replicate r, coordinate v is modelled as

    x_P,r(v) = mu_P + a_P,r + c_P(v) + e_P,r(v)

a: a replicate's offset (its subset draw and initialisation), c: the part of the error at v that
every replicate shares (the gel's hard places), e: the replicate's own spatial error pattern.
c and e are Gaussian fields with the correlation (1 - nugget) exp(-h / range) (+ nugget at h = 0);
c_P and c_80 are correlated (kappa). Each component is estimated from validation_mse.csv by
moments (the two-way table replicates x coordinates, corrected for the fitted spatial correlation),
the correlation from the pooled semivariogram of the fields. Then, for designs of R replicates and
validation grids of several spacings over the same gel area, simulated studies run the very tests of
threedcal.evaluate.ablation on the same spatial blocks; the table gives the share that detects a
change of +margin, that shows equivalence at no change, and the false-positive rates of both.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib import ticker
from scipy import optimize

from threedcal.errors import ConfigError
from threedcal.evaluate.ablation import (
    ALPHA,
    EQUIVALENCE_ALPHA,
    MARGIN,
    REFERENCE_P,
    difference_test,
    spatial_blocks,
    tost,
)
from threedcal.plotting import pyplot

VALIDATION_FRACTION = 0.2
POWER_TARGET = 0.8
DESIGN_REPLICATES = (1, 2, 3, 5, 10)
POWER_COLUMNS = [
    "P",
    "replicates",
    "spacing_mm",
    "validation_points",
    "blocks",
    "power_detect",
    "power_equivalence",
    "false_positive_rate",
    "false_equivalence_rate",
    "mean_mse",
    "sd_replicate",
    "sd_shared",
    "sd_model",
    "kappa",
    "range_mm",
    "nugget",
    "observed",
]


def correlation(distance: np.ndarray, range_mm: float, nugget: float) -> np.ndarray:
    """(1 - nugget) exp(-h / range) off the diagonal (h > 0), 1 at h = 0."""
    rho = (1.0 - nugget) * np.exp(-np.asarray(distance, float) / max(range_mm, 1e-9))
    return np.where(np.asarray(distance) == 0, 1.0, rho)


def fit_correlation(
    fields: Sequence[np.ndarray], xy: np.ndarray, bins: int = 12
) -> tuple[float, float]:
    """(range_mm, nugget) of the pooled, standardised semivariogram of `fields` (each (n,) on xy)."""
    distance = np.linalg.norm(xy[:, None] - xy[None], axis=-1)
    upper = np.triu_indices(len(xy), 1)
    h = distance[upper]
    edges = np.linspace(0, np.ptp(h) / 2 if h.size else 1.0, bins + 1)
    which = np.digitize(h, edges) - 1
    keep = (which >= 0) & (which < bins)
    gamma, weight = np.zeros(bins), np.zeros(bins)
    for field in fields:
        z = np.asarray(field, float)
        sd = z.std()
        if not np.isfinite(sd) or sd == 0:
            continue
        z = (z - z.mean()) / sd
        half = 0.5 * (z[upper[0]] - z[upper[1]]) ** 2
        gamma += np.bincount(which[keep], half[keep], bins)
        weight += np.bincount(which[keep], minlength=bins)
    if not weight.any():
        return 1.0, 1.0  # nothing varies: no spatial structure to speak of
    centre = 0.5 * (edges[1:] + edges[:-1])
    used = weight > 0
    centre, gamma, weight = centre[used], gamma[used] / weight[used], weight[used]
    # gamma(h) = nugget_part + spatial_part · (1 - exp(-h / range)): non-negative least squares for
    # the two parts at each range, the sill left free (standardising by the sample variance
    # underestimates it when the field is correlated over much of the gel)
    best = (np.inf, 1.0, 1.0)
    root = np.sqrt(weight)
    for range_mm in np.geomspace(0.05, 50.0, 200):
        design = np.column_stack([np.ones_like(centre), 1 - np.exp(-centre / range_mm)])
        parts, residual = optimize.nnls(design * root[:, None], gamma * root)
        if parts.sum() > 0 and residual < best[0]:
            best = (residual, float(range_mm), float(parts[0] / parts.sum()))
    return best[1], best[2]


def _wide(table: pd.DataFrame) -> dict[int, pd.DataFrame]:
    if "replicate" not in table:
        table = table.assign(replicate=0)
    return {
        int(p): part.pivot(index="replicate", columns="point", values="mse").sort_index(axis=1)
        for p, part in table.groupby("P")
    }


def variance_components(
    table: pd.DataFrame, reference: int = REFERENCE_P
) -> tuple[pd.DataFrame, float, float]:
    """Per P: mean, sd_replicate, sd_shared, sd_model, kappa (correlation of its shared field with
    the reference's); and the fitted (range_mm, nugget). With one replicate, sd_replicate and
    sd_model cannot be told apart from the rest: they are 0 and all variance is shared."""
    wide = _wide(table)
    if reference not in wide:
        raise ConfigError(f"the power table needs the reference fraction P={reference}")
    coords = table.drop_duplicates("point").set_index("point").sort_index()
    xy = coords.loc[wide[reference].columns, ["x_mm", "y_mm"]].to_numpy(float)
    fields = []
    for frame in wide.values():
        x = frame.to_numpy(float)
        fields.append(x.mean(axis=0))
        if x.shape[0] > 1:
            fields += list(x - x.mean(axis=1, keepdims=True) - x.mean(axis=0) + x.mean())
    range_mm, nugget = fit_correlation(fields, xy)
    n = xy.shape[0]
    corr = correlation(np.linalg.norm(xy[:, None] - xy[None], axis=-1), range_mm, nugget)
    mean_corr = corr.mean()  # variance share of a field's spatial mean
    off = (corr.sum() - n) / (n * (n - 1))  # mean correlation of two distinct coordinates
    shrink = max(1.0 - off, 1e-6)  # E[sample variance] = variance · (1 - off)
    rows = {}
    for p, frame in wide.items():
        x = frame.to_numpy(float)
        replicates = x.shape[0]
        col = x.mean(axis=0)
        if replicates > 1:
            residual = x - x.mean(axis=1, keepdims=True) - col + x.mean()
            sd_model2 = (residual**2).sum() / ((replicates - 1) * (n - 1)) / shrink
            sd_shared2 = max(0.0, col.var(ddof=1) / shrink - sd_model2 / replicates)
            sd_rep2 = max(0.0, x.mean(axis=1).var(ddof=1) - sd_model2 * mean_corr)
        else:
            sd_model2, sd_rep2 = 0.0, 0.0
            sd_shared2 = col.var(ddof=1) / shrink
        rows[p] = {
            "P": p,
            "mean_mse": float(x.mean()),
            "sd_replicate": float(np.sqrt(sd_rep2)),
            "sd_shared": float(np.sqrt(sd_shared2)),
            "sd_model": float(np.sqrt(sd_model2)),
            "_col": col,
        }
    ref = rows[reference]
    for row in rows.values():
        cov = np.cov(row["_col"], ref["_col"])[0, 1] / shrink
        scale = row["sd_shared"] * ref["sd_shared"]
        row["kappa"] = float(np.clip(cov / scale, -1, 1)) if scale > 0 else 0.0
    frame = pd.DataFrame([{k: v for k, v in r.items() if k != "_col"} for r in rows.values()])
    return frame.sort_values("P").reset_index(drop=True), range_mm, nugget


def design_coordinates(
    bounds: tuple[float, float, float, float],
    spacing_mm: float,
    rng: np.random.Generator,
    validation_fraction: float = VALIDATION_FRACTION,
) -> np.ndarray:
    """A random validation share of a square grid of `spacing_mm` over (x0, x1, y0, y1)."""
    x0, x1, y0, y1 = bounds
    xs = np.arange(x0, x1 + 1e-9, spacing_mm)
    ys = np.arange(y0, y1 + 1e-9, spacing_mm)
    grid = np.stack(np.meshgrid(xs, ys), axis=-1).reshape(-1, 2)
    count = max(2, int(round(validation_fraction * len(grid))))
    return grid[np.sort(rng.choice(len(grid), count, replace=False))]


def _block_operator(xy: np.ndarray, block_mm: float, range_mm: float, nugget: float):
    """(K, n) matrix B: B @ z are the block means of a unit-variance field L z."""
    blocks = spatial_blocks(
        pd.DataFrame({"point": np.arange(len(xy)), "x_mm": xy[:, 0], "y_mm": xy[:, 1]}),
        block_mm,
    ).to_numpy()
    corr = correlation(np.linalg.norm(xy[:, None] - xy[None], axis=-1), range_mm, nugget)
    lower = np.linalg.cholesky(corr + 1e-9 * np.eye(len(xy)))
    members = np.zeros((blocks.max() + 1, len(xy)))
    members[blocks, np.arange(len(xy))] = 1.0
    members /= members.sum(axis=1, keepdims=True)
    return members @ lower


def simulate_design(
    components: pd.DataFrame,
    xy: np.ndarray,
    block_mm: float,
    range_mm: float,
    nugget: float,
    replicates: Sequence[int],
    margin: float,
    alpha: float,
    equivalence_alpha: float,
    comparisons: int,
    simulations: int,
    rng: np.random.Generator,
    reference: int = REFERENCE_P,
) -> pd.DataFrame:
    """Simulated studies of one validation design: the rejection rates of every P and R."""
    operator = _block_operator(xy, block_mm, range_mm, nugget)
    blocks = operator.shape[0]
    if blocks < 2:
        return pd.DataFrame()
    most = max(replicates)

    def fields(count: int) -> np.ndarray:  # (simulations, count, K) block means of unit fields
        return np.stack(
            [(operator @ rng.standard_normal((len(xy), simulations))).T for _ in range(count)],
            axis=1,
        )

    shared_ref, shared_own = fields(1)[:, 0], fields(1)[:, 0]
    model = {"ref": fields(most), "own": fields(most)}
    offsets = {
        "ref": rng.standard_normal((simulations, most)),
        "own": rng.standard_normal((simulations, most)),
    }
    by_p = components.set_index("P")
    ref = by_p.loc[reference]
    rows = []
    for p, row in by_p.iterrows():
        if p == reference:
            continue
        kappa = float(row["kappa"])
        own_shared = kappa * shared_ref + np.sqrt(max(0.0, 1 - kappa**2)) * shared_own
        for count in replicates:
            reference_means = (
                ref["mean_mse"]
                + ref["sd_replicate"] * offsets["ref"][:, :count, None]
                + ref["sd_shared"] * shared_ref[:, None, :]
                + ref["sd_model"] * model["ref"][:, :count]
            )
            noise = (
                row["sd_replicate"] * offsets["own"][:, :count, None]
                + row["sd_shared"] * own_shared[:, None, :]
                + row["sd_model"] * model["own"][:, :count]
            )
            null = ref["mean_mse"] + noise
            shifted = ref["mean_mse"] * (1 + margin) + noise
            _, _, p_null = difference_test(null, reference_means)
            t_shift, _, p_shift = difference_test(shifted, reference_means)
            *_, p_eq_null = tost(null, reference_means, margin)
            *_, p_eq_shift = tost(shifted, reference_means, margin)
            level = alpha / comparisons  # Holm's first step: the hardest a comparison faces
            rows.append(
                {
                    "P": int(p),
                    "replicates": int(count),
                    "validation_points": len(xy),
                    "blocks": blocks,
                    "power_detect": float(np.mean((p_shift < level) & (t_shift > 0))),
                    "power_equivalence": float(np.mean(p_eq_null < equivalence_alpha)),
                    "false_positive_rate": float(np.mean(p_null < level)),
                    "false_equivalence_rate": float(np.mean(p_eq_shift < equivalence_alpha)),
                }
            )
    return pd.DataFrame(rows)


def power_table(
    table: pd.DataFrame,
    block_mm: float,
    spacing_mm: float,
    margin: float = MARGIN,
    alpha: float = ALPHA,
    equivalence_alpha: float = EQUIVALENCE_ALPHA,
    simulations: int = 1000,
    seed: int = 0,
    replicates: Sequence[int] = DESIGN_REPLICATES,
    reference: int = REFERENCE_P,
) -> pd.DataFrame:
    """power.csv: the simulated rates for R in `replicates` (and the study's own R) on validation
    grids of 2x, 1x and 0.5x the study's probe spacing over its gel area. `observed` marks the
    study's own design (its R at its spacing)."""
    components, range_mm, nugget = variance_components(table, reference)
    observed_r = int(table["replicate"].nunique()) if "replicate" in table else 1
    designs = sorted(set(replicates) | {observed_r})
    coords = table.drop_duplicates("point")
    bounds = (
        float(coords["x_mm"].min()),
        float(coords["x_mm"].max()),
        float(coords["y_mm"].min()),
        float(coords["y_mm"].max()),
    )
    comparisons = max(1, len(components) - 1)
    rng = np.random.default_rng([int(seed), 0x9077E])
    tables = []
    for factor in (2.0, 1.0, 0.5):
        spacing = spacing_mm * factor
        xy = design_coordinates(bounds, spacing, rng)
        result = simulate_design(
            components,
            xy,
            block_mm,
            range_mm,
            nugget,
            designs,
            margin,
            alpha,
            equivalence_alpha,
            comparisons,
            simulations,
            rng,
            reference,
        )
        if not result.empty:
            tables.append(
                result.assign(
                    spacing_mm=spacing,
                    observed=(factor == 1.0) & (result["replicates"] == observed_r),
                )
            )
    if not tables:
        raise ConfigError(
            "the validation coordinates fill one spatial block: no design can be simulated"
        )
    power = pd.concat(tables, ignore_index=True).merge(components, on="P", how="left")
    power["range_mm"] = range_mm
    power["nugget"] = nugget
    return (
        power[POWER_COLUMNS].sort_values(["P", "spacing_mm", "replicates"]).reset_index(drop=True)
    )


def needed_design(power: pd.DataFrame, p: int, column: str = "power_equivalence") -> str:
    """The cheapest simulated design (fewest replicates, then widest spacing) reaching 80 % power.
    One replicate is never named: its test cannot see the replicate variance, so what it rejects
    is not power (its false-positive rate is far above alpha; power_figure draws it apart)."""
    candidates = power[(power["P"] == p) & (power["replicates"] >= 2)]
    if candidates.empty:
        return "—"
    part = candidates[candidates[column] >= POWER_TARGET]
    if part.empty:
        best = candidates.sort_values(column).iloc[-1]
        return (
            f"none of the simulated designs (best: {best[column]:.0%} with "
            f"{int(best['replicates'])} replicates at {best['spacing_mm']:g} mm)"
        )
    best = part.sort_values(["replicates", "spacing_mm"], ascending=[True, False]).iloc[0]
    return (
        f"{int(best['replicates'])} replicates at {best['spacing_mm']:g} mm "
        f"({int(best['validation_points'])} validation points): {best[column]:.0%}"
    )


def power_figure(power: pd.DataFrame, path: str | Path, title: str) -> None:
    """Power against replicates for each P: solid = detect a +margin change, dashed = show
    equivalence at no change; one colour per validation spacing; the study's design ringed.
    R = 1 stands apart (crosses): its test cannot see the replicate variance and is too liberal."""
    plt = pyplot()

    fractions = sorted(power["P"].unique())
    fig, axes = plt.subplots(
        1,
        len(fractions),
        figsize=(2.6 * len(fractions) + 0.6, 3.6),
        dpi=120,
        sharey=True,
        squeeze=False,
    )
    spacings = sorted(power["spacing_mm"].unique())
    colours = plt.cm.plasma(np.linspace(0.1, 0.8, len(spacings)))
    for ax, p in zip(axes[0], fractions, strict=True):
        part = power[power["P"] == p]
        for colour, spacing in zip(colours, spacings, strict=True):
            line = part[part["spacing_mm"] == spacing].sort_values("replicates")
            if line.empty:
                continue
            points = int(line["validation_points"].iloc[0])
            many, one = line[line["replicates"] > 1], line[line["replicates"] == 1]
            ax.plot(
                many["replicates"],
                many["power_detect"],
                "o-",
                c=colour,
                ms=3,
                label=f"{spacing:g} mm ({points} val. points)",
            )
            ax.plot(many["replicates"], many["power_equivalence"], "s--", c=colour, ms=3)
            ax.plot(one["replicates"], one["power_detect"], "x", c=colour, ms=5)
            ax.plot(one["replicates"], one["power_equivalence"], "+", c=colour, ms=6)
        mine = part[part["observed"].astype(bool)]
        ax.plot(mine["replicates"], mine["power_detect"], "o", mfc="none", mec="k", ms=8)
        ax.plot(mine["replicates"], mine["power_equivalence"], "s", mfc="none", mec="k", ms=8)
        ax.axhline(POWER_TARGET, c="grey", lw=0.6, ls=":")
        ticks = sorted(part["replicates"].unique())
        ax.set(xscale="log", xlabel="replicates R", title=f"P = {p} %", ylim=(-0.02, 1.02))
        ax.set_xticks(ticks, [str(r) for r in ticks])
        ax.xaxis.set_minor_locator(ticker.NullLocator())
    axes[0, 0].set_ylabel("power")
    axes[0, -1].legend(fontsize=6, loc="lower right")
    fig.suptitle(
        f"{title}\nsolid: detect a +margin change, dashed: show equivalence at no change; "
        "rings: this study; R = 1 (crosses) is too liberal",
        fontsize=9,
    )
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
