"""results/environment.json: versions, threads, seeds and hardware of a run, for the results page
and the summary."""

from __future__ import annotations

import os
import platform
from collections.abc import Mapping
from typing import Any

import torch

from threedcal.model.machine import cpu_capability, cpu_flags, isa_limits, native_bfloat16
from threedcal.study.paths import package_versions


def environment(config: Mapping) -> dict[str, Any]:
    """Versions, threads, seeds and hardware of this run (for the report and summary)."""
    cpu, flags = cpu_flags()
    return {
        "platform": platform.platform(),
        "processor": platform.processor() or platform.machine(),
        "cpu": cpu,
        "cpu_flags": " ".join(flags),
        "isa_limits": ", ".join(f"{k}={v}" for k, v in isa_limits().items()) or "none",
        "torch_cpu_capability": cpu_capability(),
        "native_bfloat16": native_bfloat16(),
        "cpu_count": os.cpu_count(),
        "cuda": torch.cuda.is_available(),
        "seed": config.get("seed"),
        "torch_threads": config.get("torch_threads"),
        # what this job's BLAS/OpenMP pools were given: Snakemake sets them to the job's threads
        "thread_environment": {
            name: os.environ.get(name)
            for name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")
        },
        "scene_seeds": {name: s["seed"] for name, s in config["scenes"].items()},
        "software": package_versions(),
    }
