"""The study layer: the config parsed and checked (config), a scene's typed settings (scene,
pressing, training), the workflow's files (paths), and the stages that compose the domain packages
for one rule each (session, dataset_stage, stats_stage, presets_stage, reskin_stages, imported_jobs,
the quick calibration's quick_*).
Domain packages never import from here."""
