"""What this machine's CPU runs natively, and the arithmetic and threads chosen from it at run time.

A default that suits one host can be ruinous on another: bfloat16 training is 1.65x faster than
float32 on a CPU with AVX-512 BF16 and about 7x slower on one with AVX2 only, where oneDNN emulates
it. So `precision: auto` asks torch what the CPU and the run-time caps allow (ATen's dispatch level,
oneDNN's `ONEDNN_MAX_CPU_ISA`) and picks bfloat16 only where the instructions are native. The
choice is a function of the machine and its environment alone, never of a timing, so the same host
always trains the same bytes; `make bench` measures both arithmetics and says whether the choice was
the faster one there.
"""

from __future__ import annotations

import os
from functools import lru_cache
from pathlib import Path

import torch

from threedcal.errors import ConfigError

PRECISIONS = ("auto", "float32", "bfloat16")
# oneDNN's instruction-set caps (ONEDNN_MAX_CPU_ISA, formerly DNNL_MAX_CPU_ISA) that still include
# native bfloat16; any other cap (AVX2, AVX512_CORE, ...) makes oneDNN emulate it.
_BF16_ISA_CAPS = {
    "ALL",
    "AVX512_CORE_BF16",
    "AVX512_CORE_FP16",
    "AVX512_CORE_AMX",
    "AVX512_CORE_AMX_FP16",
    "AVX10_1_512",
    "AVX10_1_512_AMX",
    "AVX10_1_512_AMX_FP16",
    "AVX10_2_512",
    "AVX10_2_512_AMX_2",
}


@lru_cache(maxsize=1)
def cpu_capability() -> str:
    """ATen's CPU dispatch level (DEFAULT, AVX2, AVX512; ATEN_CPU_CAPABILITY caps it)."""
    return str(torch.backends.cpu.get_cpu_capability())


@lru_cache(maxsize=1)
def native_bfloat16() -> bool:
    """True where the CPU has bfloat16 arithmetic in hardware (AVX-512 BF16 or AMX) and both
    torch's dispatch and oneDNN are allowed to use it."""
    hardware = torch.cpu._is_avx512_bf16_supported() or torch.cpu._is_amx_tile_supported()
    cap = os.environ.get("ONEDNN_MAX_CPU_ISA") or os.environ.get("DNNL_MAX_CPU_ISA") or "ALL"
    allowed = (
        cpu_capability() == "AVX512"
        and torch.ops.mkldnn._is_mkldnn_bf16_supported()
        and cap.strip().upper() in _BF16_ISA_CAPS
    )
    return bool(hardware and allowed)


# Networks whose bfloat16 gradients follow float32's (tests/model/test_model.py checks them at the
# study's step shape). `multiscale`'s 24-channel dilated convolutions come out NaN in channels-last
# bfloat16 on torch 2.13 (docs/explanation/models.md), so `auto` keeps it, and any network not listed, in float32.
BFLOAT16_SAFE = ("context", "context_half")


def torch_device(name: str | None, key: str = "model.device") -> torch.device:
    """`name` as a torch device (`auto` or None: CUDA when present, else the CPU), refused with the
    setting's `key` when it names no device type or a CUDA device this torch cannot reach: a raw
    torch assertion would otherwise end a training after its collection."""
    if name in (None, "auto"):
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    try:
        device = torch.device(name)
    except (RuntimeError, TypeError) as exc:
        raise ConfigError(
            f"{key}: {name!r} is no torch device (auto, cpu, cuda, cuda:1, ...)"
        ) from exc
    if device.type == "cuda":
        count = torch.cuda.device_count() if torch.cuda.is_available() else 0
        if count == 0:
            raise ConfigError(
                f"{key}: {name!r}, but torch {torch.__version__} sees no CUDA device (a CPU build "
                "of torch, or no driver): use auto or cpu, or install a CUDA build"
            )
        if device.index is not None and device.index >= count:
            raise ConfigError(f"{key}: {name!r}, but torch sees {count} CUDA device(s)")
    return device


def resolve_precision(precision: str, device: torch.device, preset: str | None = None) -> str:
    """The arithmetic a training on `device` runs in: `auto` → bfloat16 on a CPU with
    native_bfloat16 where the network is known to train in it (`preset` in BFLOAT16_SAFE; None:
    not asked), float32 elsewhere. On a GPU these small networks are bound by kernel launches, not
    arithmetic: bfloat16's casts only add kernels (docs/explanation/models.md)."""
    if precision not in PRECISIONS:
        raise ConfigError(f"model.precision: {precision!r} (allowed: {', '.join(PRECISIONS)})")
    if precision != "auto":
        return precision
    if preset is not None and preset not in BFLOAT16_SAFE:
        return "float32"
    if device.type == "cpu":
        return "bfloat16" if native_bfloat16() else "float32"
    return "float32"


def usable_cores() -> int:
    """CPU cores this process may run on (its affinity mask; a container's or a Slurm job's)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not Linux
        return max(1, os.cpu_count() or 1)


def describe() -> dict:
    """What a result records of the machine it was computed on."""
    return {
        "cpu_capability": cpu_capability(),
        "native_bfloat16": native_bfloat16(),
        "cores": usable_cores(),
        "torch": str(torch.__version__),
    }


def cpu_flags() -> tuple[str, list[str]]:
    """The CPU's model name and its vector instruction sets (AVX2, FMA, AVX-512, AMX) as Linux
    lists them: what every speed figure, and a torch result's last bits, depend on."""
    name, flags = "unknown CPU", set()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            key, _, value = line.partition(":")
            if key.strip() == "model name":
                name = value.strip()
            elif key.strip() == "flags":
                flags = set(value.split())
    except OSError:
        pass
    vector = sorted(f for f in flags if f.startswith(("avx512", "amx")) or f in ("avx2", "fma"))
    return name, vector


def isa_limits() -> dict[str, str]:
    """The run-time caps set on torch's and numpy's kernels (an AVX2 machine emulated on a newer one)."""
    names = ("ONEDNN_MAX_CPU_ISA", "DNNL_MAX_CPU_ISA", "ATEN_CPU_CAPABILITY", "OPENBLAS_CORETYPE")
    return {k: os.environ[k] for k in names if k in os.environ}


def host_line() -> str:
    """One line naming the host for a benchmark's figures."""
    name, vector = cpu_flags()
    limits = ", ".join(f"{k}={v}" for k, v in isa_limits().items())
    return (
        f"{name}; flags: {' '.join(vector) or 'none found'}"
        + (f"; limited by {limits}" if limits else "")
        + f"; torch dispatches {cpu_capability()}; native bfloat16: "
        + ("yes" if native_bfloat16() else "no")
    )
