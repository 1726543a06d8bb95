"""A new unit calibrated in a few rounds of presses, stopped when more presses no longer pay."""
