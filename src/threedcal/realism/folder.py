"""The realism check of one real folder: the profile's optics fitted on one half of its presses
(threedcal.realism.fit) and compared, figure by figure, with the other half (threedcal.realism.check,
threedcal.realism.halo2d)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from threedcal.errors import ConfigError
from threedcal.profiles import load_profile, with_gel_mechanics
from threedcal.realism.check import (
    LABELLED_ONLY,
    compare,
    format_table,
    image_groups,
    load_ball_dataset,
    render_presses,
)
from threedcal.realism.fit import fit_optics
from threedcal.realism.halo2d import folder_halos, format_halos

# ------------------------------------------------------------------------- the split
MIN_IMAGES = 4


def split_halves(labels: Sequence, seed: int, group_px: float = 4.0, *, where: str = ""):
    """(fitting, evaluation) label lists: the press groups shuffled by `seed`, alternately dealt to
    the half that has fewer images so far, so no press (and no image) is in both."""
    if len(labels) < MIN_IMAGES:
        raise ConfigError(
            f"{where or 'dataset'}: {len(labels)} contact images; fitting on one half and "
            f"comparing on the other needs at least {MIN_IMAGES}"
        )
    groups = image_groups(labels, group_px)
    if len(groups) < 2:
        raise ConfigError(f"{where or 'dataset'}: every image is one press; cannot split")
    order = np.random.default_rng(int(seed)).permutation(len(groups))
    halves: tuple[list[int], list[int]] = ([], [])
    for g in order:
        target = 0 if len(halves[0]) <= len(halves[1]) else 1
        halves[target].extend(groups[g])
    return tuple([labels[i] for i in sorted(half)] for half in halves)


# ------------------------------------------------------------------------- the report
@dataclass
class RealismRun:
    """A realism check of one folder: the table as text, whether every figure passed, and the 2-D
    halo comparison (threedcal.realism.halo2d; None in sample)."""

    text: str
    ok: bool
    halo: Any = None


def realism_report(
    real: str | Path,
    sensor: str,
    seed: int = 0,
    out: str | Path | None = None,
    **kwargs,
) -> tuple[str, bool]:
    """The side-by-side table as text (and written to `out`), and whether every figure passed:
    `realism_run`'s text and verdict."""
    run = realism_run(real, sensor, seed, out, **kwargs)
    return run.text, run.ok


def realism_run(
    real: str | Path,
    sensor: str,
    seed: int = 0,
    out: str | Path | None = None,
    *,
    split_seed: int = 0,
    fit: bool = True,
    fitted_out: str | Path | None = None,
    gel_mechanics: str | None = None,
) -> RealismRun:
    """The realism check of one real folder.

    `fit` (the default): the real images are split into two halves by press (`split_seed`), the
    profile's photometric constants are fitted to one half and background.png
    (threedcal.realism.fit), and the table compares the fitted optics with the *other* half only: out
    of sample, the radial figures (threedcal.realism.check) and the 2-D halo (threedcal.realism.halo2d,
    the fitting half's real frames as its reference); `fitted_out` receives the fitted profile
    (YAML). `fit=False`: the profile as it is, against every image (and the background frame), no
    2-D halo (it needs two real halves). `gel_mechanics`: the gel's model in place of the profile's
    (threedcal.profiles.with_gel_mechanics), as a scene's bench simulates it."""
    profile = with_gel_mechanics(load_profile("sensor", sensor), gel_mechanics)
    data = load_ball_dataset(real, profile["image"].get("orientation"))
    head = (
        f"realism: {profile['name']} optics ({profile['gel'].get('mechanics', 'geometric')} gel) "
        f"at {data.width_px}x{data.height_px}, "
        f"{data.px_per_mm} px/mm, ball {data.ball_radius_mm} mm, {len(data.labels)} "
        f"{'labelled' if data.labelled else 'unlabelled (contacts located from frame - background)'}"
        f" images of {data.root}"
        f"{f', read turned a quarter {data.turn} into the profile frame' if data.turn else ''}"
    )
    lines = [head]
    halo = None
    if fit:
        fit_half, test_half = split_halves(data.labels, split_seed, where=str(data.root))
        fitted = fit_optics(profile, data, fit_half)
        if fitted_out is not None:
            fitted.write_profile(fitted_out)
        renders = render_presses(data, fitted.profile, seed, test_half)
        rows = compare(
            data,
            fitted.profile,
            seed=seed,
            labels=test_half,
            background_is_real=False,
            renders=renders,
        )
        halo = folder_halos(data, test_half, fit_half, renders, seed=seed)
        lines += [
            f"OUT OF SAMPLE: optics fitted on {len(fit_half)} images + background.png "
            f"(split_seed {split_seed}, presses kept together), figures on the other "
            f"{len(test_half)} images only ({', '.join(lb.image for lb in test_half)}); "
            "background.png is the reference for contact changes, not a real figure",
        ]
    else:
        rows = compare(data, profile, seed=seed)
        lines.append("IN SAMPLE: the profile as it is, against every image and background.png")
    if not data.labelled:
        lines.append(
            "not checked without labels: "
            + ", ".join(LABELLED_ONLY)
            + " (true normals and a contact radius not measured from the image)"
        )
    bad = [r["figure"] for r in rows if not r["ok"]]
    lines += [
        format_table(rows),
        f"realism: FAIL, out of the real range by more than the tolerance: {', '.join(bad)}"
        if bad
        else "realism: ok, every simulated figure within the real range and tolerance",
    ]
    if halo is not None:
        lines.append(format_halos(halo))
    if fit:
        lines.append(fitted.summary())
    text = "\n".join(lines) + "\n"
    if out is not None:
        Path(out).write_text(text)
    return RealismRun(text, not bad and (halo is None or halo.ok), halo)
