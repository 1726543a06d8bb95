"""CPU seconds of the ablation's statistics on a finished study: the three test families and the
power table, from its validation_mse.csv (docs/explanation/statistics.md, "Cost").

    .venv/bin/python docs/diagnostics/ablation_stats_cost.py WORKDIR SCENE [SIMULATIONS]
"""

import sys
import time
from pathlib import Path

import pandas as pd

from threedcal.dataset.trainset import TrainingSet
from threedcal.evaluate.ablation import ablation_tests, spatial_blocks
from threedcal.evaluate.power import power_table
from threedcal.evaluate.validation import probe_spacing_mm, scoring_disc_mm


def main(workdir: str, scene: str, simulations: int = 1000) -> None:
    root = Path(workdir) / "results" / scene
    table = pd.read_csv(root / "stats" / "validation_mse.csv")
    splits = pd.read_csv(root / "dataset" / "splits.csv")
    block_mm = scoring_disc_mm(TrainingSet.load(root / "dataset" / "trainset"))
    began = time.process_time()
    ablation_tests(table, spatial_blocks(table, block_mm))
    tested = time.process_time()
    power_table(table, block_mm, probe_spacing_mm(splits), simulations=simulations)
    done = time.process_time()
    print(
        f"{scene}: {table['point'].nunique()} validation points, {len(table)} model x point rows: "
        f"tests {tested - began:.2f} s CPU, power table ({simulations} simulations) "
        f"{done - tested:.2f} s CPU"
    )


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2], *(int(a) for a in sys.argv[3:4]))
