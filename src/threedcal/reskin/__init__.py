"""ReSkin calibration: readings from a collection store → a contact-localisation MLP → its errors.

data.py (baseline-subtracted field readings, split by probe coordinate), model.py (the MLP, its
deterministic training and checkpoints), evaluate.py (localisation and depth errors on held-out
coordinates), figures.py (sample readings; the Fig. 7B-style map of held-out predictions).
"""
