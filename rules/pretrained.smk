# Target `pretrained` (not part of `all`; `make pretrained` runs it and installs the result): the
# weights the package ships for `model.init: pretrained`, one network per built-in vision sensor,
# trained on simulated presses of many units (docs/explanation/models.md, Pretrained weights).


rule pretrain:
    output:
        model=f"{PRETRAINED_DIR}/model.pt",
        provenance=f"{PRETRAINED_DIR}/provenance.json",
        losses=f"{PRETRAINED_DIR}/losses.csv",
        figure=f"{PRETRAINED_DIR}/losses.png",
    log:
        "results/pretrained/logs/pretrain_{sensor}.log",
    benchmark:
        "results/pretrained/benchmarks/pretrain_{sensor}.tsv"
    wildcard_constraints:
        sensor=one_of(config["pretraining"]["sensors"]),
    conda:
        CONDA_ENV
    threads: config["pretraining"]["torch_threads"]
    params:
        pretraining=config["pretraining"],
        code=code_digest("pretrain.py"),
    script:
        "../scripts/pretrain.py"


rule pretrained:
    input:
        expand(
            f"{PRETRAINED_DIR}/model.pt",
            sensor=config["pretraining"]["sensors"],
        ),
