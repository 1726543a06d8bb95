# Helpers shared by the rules.


def code_digest(script):
    """Digest of a script and every library module it runs: a rerun reason when it changes.
    Each step passes its own script (tests/test_provenance.py checks that they agree).
    """
    return script_digest(Path(workflow.basedir) / "scripts" / script)


def scene_models(wildcards):
    """{"P5": "results/{scene}/models/P5/model.pt", ...}: every model of a scene, keyed by fraction."""
    fractions = training_fractions(config["scenes"][wildcards.scene])
    return {
        f"P{p}": f"results/{wildcards.scene}/models/P{p}/model.pt" for p in fractions
    }


def ablation_losses(wildcards):
    fractions = training_fractions(config["scenes"][wildcards.scene])
    return [f"results/{wildcards.scene}/models/P{p}/losses.csv" for p in fractions]


def cv_models(wildcards):
    """{"model": [fold0 ... foldK-1 model.pt], "lookup": [...]}: every fold model ball_eval scores."""
    folds = config["scenes"][wildcards.scene]["cv"]["folds"]
    return {
        method: [
            f"results/{wildcards.scene}/cv/{method}/fold{fold}/model.pt"
            for fold in range(folds)
        ]
        for method in CV_METHODS
    }
