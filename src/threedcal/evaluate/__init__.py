"""Evaluation: ablation statistics, test objects, alignment and error metrics."""
