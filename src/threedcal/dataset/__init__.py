"""From raw probe frames to model-ready data: registration, exact labels, splits, importers."""
