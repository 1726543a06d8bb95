"""Rule `sim2real_train`: one fold's model on k of its real training images, fine-tuned from the
sim-pretrained model (sim_real) or from scratch (real_only) with the same budget, or the shipped
weights fine-tuned at their frame size (shipped_real)."""

from threedcal.logs import stage_log
from threedcal.model.sim2real import parse_k, train_k

with stage_log(snakemake.log[0]):
    train_k(
        snakemake.input.trainset,
        snakemake.input.folds,
        int(snakemake.wildcards.fold),
        parse_k(snakemake.wildcards.k),
        snakemake.wildcards.condition,
        snakemake.params.model,
        snakemake.params.sim_to_real,
        snakemake.params.seed,
        snakemake.params.threads,
        snakemake.output.model.rsplit("/", 1)[0],
        pretrained=snakemake.input.get("pretrained"),
    )
