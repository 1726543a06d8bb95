"""Rule `ball_eval`: cross-validated gradient RMSE and cap depth MAE (with intervals) of the scene's
model and of the lookup baseline on the imported real images."""

from threedcal.evaluate.ball_eval import ball_eval
from threedcal.logs import stage_log

with stage_log(snakemake.log[0]):
    ball_eval(
        snakemake.input.trainset,
        snakemake.input.folds,
        {method: list(snakemake.input[method]) for method in ("model", "lookup")},
        snakemake.params.cv,
        snakemake.params.seed,
        snakemake.params.threads,
        snakemake.output.json,
        snakemake.output.images,
        snakemake.output.figure,
        preset=snakemake.params.preset,
    )
