"""Probe plans, the labelled Zarr store, and the resumable collection run."""
