"""`threedcal sim realism`: the optical simulator's figures beside a real ball dataset's."""

from __future__ import annotations

import argparse
from pathlib import Path

from threedcal.errors import ConfigError
from threedcal.realism.folder import realism_report


def run_sim_realism(args: argparse.Namespace) -> int:
    if args.in_sample and args.write_fitted:
        raise ConfigError("--write-fitted needs the fit: leave out --in-sample")
    if args.write_fitted:  # checked before the fit: it takes minutes, then writes
        fitted = Path(args.write_fitted)
        if fitted.exists():
            raise ConfigError(
                f"--write-fitted {fitted}: already exists; refusing to overwrite it (a profile "
                "you may have tuned): choose another path or move it away"
            )
        if not fitted.parent.is_dir():
            raise ConfigError(f"--write-fitted {fitted}: folder {fitted.parent} does not exist")
    text, ok = realism_report(
        args.real,
        args.sensor,
        seed=args.seed,
        split_seed=args.split_seed,
        fit=not args.in_sample,
        fitted_out=args.write_fitted,
        gel_mechanics=args.gel_mechanics,
    )
    print(text, end="")
    return 0 if ok else 1
