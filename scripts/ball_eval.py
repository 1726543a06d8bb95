"""Rule `ball_eval`: held-out gradient RMSE and cap depth MAE of the model and the lookup baseline."""

from threedcal.logs import stage_log
from threedcal.model.ball_eval import ball_eval

with stage_log(snakemake.log[0]):
    ball_eval(
        snakemake.input.model,
        snakemake.input.trainset,
        snakemake.output[0],
        seed=snakemake.params.seed,
    )
