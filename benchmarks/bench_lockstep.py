"""Training steps/s of the ablation's N models trained together: stacked (vmap) against one at a time.

An ablation trains every replicate of a fraction the same steps (threedcal.model.lockstep). The
baseline is the loop, each model its own step one after another, as the single trainer steps; the
stacked form runs all N as one vectorised step (grouped convolutions, one AdamW). Both at the
study's step shape (context_half, 4 windows of 48 px a step, the huber loss, AdamW), in the
arithmetic `precision: auto` picks here, at each thread count. A figure is N model-steps per second
from the median of single calls (a busy machine disturbs a median less than a mean). The first line
names the CPU; run it also with ONEDNN_MAX_CPU_ISA=AVX2 ATEN_CPU_CAPABILITY=avx2 for an AVX2 laptop.

Usage: python benchmarks/bench_lockstep.py [--models N ...] [--threads T ...] [--seconds S]
"""

from __future__ import annotations

import argparse
import copy
import time

import numpy as np
import torch
from torch.func import functional_call, stack_module_state, vmap

from threedcal.model.losses import gradient_loss
from threedcal.model.machine import host_line, resolve_precision
from threedcal.model.presets import build_model, preferred_memory_format
from threedcal.model.train_step import training_autocast

PRESET, BATCH, PATCH, LOSS = "context_half", 4, 48, "huber"


def _data(models: int) -> tuple[torch.Tensor, torch.Tensor]:
    generator = torch.Generator().manual_seed(0)
    x = torch.randn(models, BATCH, 5, PATCH, PATCH, generator=generator)
    y = 0.1 * torch.randn(models, BATCH, 2, PATCH, PATCH, generator=generator)
    return x, y


def loop_step(models: int, precision: str):
    """One optimiser step of each model in turn (the baseline)."""
    torch.manual_seed(0)
    nets = [build_model(PRESET) for _ in range(models)]
    layout = preferred_memory_format(nets[0])
    for net in nets:
        net.to(memory_format=layout)
    optimizers = [torch.optim.AdamW(net.parameters(), lr=1e-3) for net in nets]
    x, y = _data(models)
    device = torch.device("cpu")

    def step():
        for net, optimizer, xi, yi in zip(nets, optimizers, x, y, strict=True):
            optimizer.zero_grad(set_to_none=True)
            with training_autocast(precision, device):
                prediction = net(xi.contiguous(memory_format=layout))
            gradient_loss(prediction.float(), yi, LOSS).backward()
            optimizer.step()

    return step


def stacked_step(models: int, precision: str):
    """One vectorised step of all models (threedcal.model.lockstep's vmap)."""
    torch.manual_seed(0)
    nets = [build_model(PRESET) for _ in range(models)]
    template = copy.deepcopy(nets[0]).to("meta")
    params, buffers = stack_module_state(nets)
    params = {k: v.detach().clone().requires_grad_() for k, v in params.items()}
    optimizer = torch.optim.AdamW(list(params.values()), lr=1e-3)
    x, y = _data(models)
    device = torch.device("cpu")

    def loss(p, b, xi, yi):
        return gradient_loss(functional_call(template, (p, b), (xi,)).float(), yi, LOSS)

    def step():
        optimizer.zero_grad(set_to_none=True)
        with training_autocast(precision, device):
            losses = vmap(loss)(params, buffers, x, y)
        losses.sum().backward()
        optimizer.step()

    return step


def model_steps_per_s(step, models: int, seconds: float) -> float:
    for _ in range(2):
        step()
    times, began = [], time.perf_counter()
    while time.perf_counter() - began < seconds or len(times) < 3:
        start = time.perf_counter()
        step()
        times.append(time.perf_counter() - start)
    return models / float(np.median(times))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", type=int, nargs="+", default=[1, 8, 16])
    parser.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--seconds", type=float, default=3.0)
    args = parser.parse_args()
    precision = resolve_precision("auto", torch.device("cpu"), PRESET)
    print(f"host: {host_line()}")
    print(f"{PRESET}, {BATCH} windows of {PATCH} px a step, {precision}; model-steps/s (median)")
    print("| threads | models | one at a time | stacked (vmap) | stacked / one at a time |")
    print("|---:|---:|---:|---:|---:|")
    for threads in args.threads:
        torch.set_num_threads(threads)
        for models in args.models:
            alone = model_steps_per_s(loop_step(models, precision), models, args.seconds)
            together = model_steps_per_s(stacked_step(models, precision), models, args.seconds)
            print(
                f"| {threads} | {models} | {alone:.1f} | {together:.1f} | {together / alone:.2f}x |",
                flush=True,
            )


if __name__ == "__main__":
    main()
