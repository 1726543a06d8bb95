"""Rule `sim2real_train`: one fold's models on k of its real training images, every k of
sim_to_real.k: fine-tuned from the sim-pretrained model (sim_real) or from scratch (real_only) with
the same budget, or the shipped weights fine-tuned at their frame size (shipped_real)."""

from threedcal.evaluate.sim2real import train_fold_ks
from threedcal.logs import stage_log

with stage_log(snakemake.log[0]):
    train_fold_ks(
        snakemake.input.trainset,
        snakemake.input.folds,
        int(snakemake.wildcards.fold),
        snakemake.wildcards.condition,
        snakemake.params.model,
        snakemake.params.sim_to_real,
        snakemake.params.seed,
        snakemake.params.threads,
        snakemake.output[0],
        pretrained=snakemake.input.get("pretrained"),
    )
