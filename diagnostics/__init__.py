"""Diagnostics: scripts that make the figures of docs/figures and measure the claims the
explanation pages make. Not part of the installed package (only src/threedcal ships); they use
only threedcal's public functions, and tests/test_diagnostics.py runs each one's `--smoke` mode.
Run them from the repository root:

| module | makes / backs | command |
|---|---|---|
| elastic_gel | elastic_checks.png, elastic_contact.png; the layer compliance (sympy), the elastic gel's label error, contact locators and registration on it | `.venv/bin/python -m diagnostics.elastic_gel [derive checks contact locators registration] --out docs/figures` |
| point_frames | point_frames.png; a ball pressed on the bench comes back where the printer put it, in the printer frame | `.venv/bin/python -m diagnostics.point_frames --out docs/figures` |
| real_cv_methods | real_cv_drawn.png, real_cv_refined.png; the methods table of the real ball folder under grouped cross-validation | `.venv/bin/python -m diagnostics.real_cv_methods [METHOD ...] --out docs/figures` |
| perfect_model_objects | what each test-object protocol reports for a perfect model (the true surface's, or the pressed gel's, gradients), after `make all` | `.venv/bin/python -m diagnostics.perfect_model_objects digit_sim [--no-mount-errors] [--gel]` |
| label_integration | exact labels integrate to the true depth; what a slope clamp (`dataset.max_slope_deg`) costs | `.venv/bin/python -m diagnostics.label_integration` |
| pretrained_edges | the shipped weights on simulated units two sigma out in every measured spread: contact against the ball's disc, false contact, centroid, gradient MSE | `.venv/bin/python -m diagnostics.pretrained_edges [--weights DIR]` |
| quick_presses | the quick calibration's presses alone: as many of the full calibration's own presses (its registration) trained as the quick loop trains, against its P = 80 models, after `make quick-study` | `.venv/bin/python -m diagnostics.quick_presses --results results` |
| registration_cost | what a registration error costs: the full calibration's presses labelled through the bench's truth, then shifted; MSE(e) = MSE(0) (1 + c e²) per sensor, after `make quick-study` | `.venv/bin/python -m diagnostics.registration_cost --results results` |
| unit_spread | the real units of data/ measured against each other: the figures the sensor profiles' `unit_variation` is set from | `.venv/bin/python -m diagnostics.unit_spread` |

Every module has `main(argv)` and a `--smoke` mode (tiny sizes, seconds, output to a temporary
folder unless `--out` is given).
"""
