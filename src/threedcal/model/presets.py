"""Network presets: the paper's TouchNet exactly, small per-pixel CPU nets, and the lookup baseline.

Every preset maps a (N, 5, H, W) float32 input — (frame − blank)/255 as three channels plus x and y
coordinate channels — to (N, 2, H, W) gradients (∂z/∂x, ∂z/∂y). `touchnet` keeps the authors'
parameter names (conv1…conv9, bn1…bn8) so their published state_dict loads unchanged.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from threedcal.errors import ConfigError
from threedcal.model import PRESET_NAMES
from threedcal.model.lookup import LOOKUP_DEFAULTS, LookupTable

INPUT_CHANNELS = 5
OUTPUT_CHANNELS = 2

# (out_channels, kernel, dropout) of TouchNet's eight hidden modules (3D Cal, Kota et al.).
TOUCHNET_LAYERS = (
    (32, 7, 0.2),
    (64, 7, 0.2),
    (128, 7, 0.2),
    (256, 5, 0.3),
    (256, 5, 0.3),
    (128, 5, 0.2),
    (64, 3, 0.2),
    (32, 3, 0.2),
)


class TouchNet(nn.Module):
    """The paper's fully convolutional net: 8 × (conv, BatchNorm, ReLU, Dropout2d), then a 1×1 head."""

    def __init__(self) -> None:
        super().__init__()
        channels = INPUT_CHANNELS
        for i, (out, kernel, drop) in enumerate(TOUCHNET_LAYERS, start=1):
            setattr(self, f"conv{i}", nn.Conv2d(channels, out, kernel, padding=kernel // 2))
            setattr(self, f"bn{i}", nn.BatchNorm2d(out))
            setattr(self, f"dropout{i}", nn.Dropout2d(drop))
            channels = out
        self.conv9 = nn.Conv2d(channels, OUTPUT_CHANNELS, kernel_size=1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        for i in range(1, len(TOUCHNET_LAYERS) + 1):
            conv, bn, drop = (getattr(self, f"{n}{i}") for n in ("conv", "bn", "dropout"))
            x = drop(F.relu(bn(conv(x))))
        return self.conv9(x)


class PixelNet(nn.Module):
    """A k×k context convolution, then 1×1 layers: a per-pixel colour+position → gradient map.

    The GelSight colour→normal relation is almost local, so a small neighbourhood plus the pixel's
    position carries most of the information at a tiny fraction of TouchNet's cost. `compact` uses
    a 7×7 neighbourhood: on real ball frames it tells the contact's rim from the deformed (but
    flat-labelled) gel around it better than 3×3, at about the same speed (README, Choosing a preset).
    """

    def __init__(self, hidden: int = 16, depth: int = 2, kernel: int = 3) -> None:
        super().__init__()
        layers: list[nn.Module] = [
            nn.Conv2d(INPUT_CHANNELS, hidden, kernel, padding=kernel // 2),
            nn.ReLU(),
        ]
        for _ in range(depth - 1):
            layers += [nn.Conv2d(hidden, hidden, 1), nn.ReLU()]
        layers.append(nn.Conv2d(hidden, OUTPUT_CHANNELS, 1))
        self.body = nn.Sequential(*layers)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.body(x)


class ContextNet(nn.Module):
    """PixelNet's 7×7 colour+position layer, then residual dilated 3×3 layers that see the contact.

    A per-pixel regressor cannot tell a mid-contact slope from a steeper one whose shading has
    saturated; where in the contact a pixel lies can. Dilations 2, 4, 8, 16 reach ±33 px.
    """

    def __init__(self, hidden: int = 16, kernel: int = 7, dilations=(2, 4, 8, 16)) -> None:
        super().__init__()
        self.stem = nn.Conv2d(INPUT_CHANNELS, hidden, kernel, padding=kernel // 2)
        self.context = nn.ModuleList(
            nn.Conv2d(hidden, hidden, 3, padding=d, dilation=d) for d in dilations
        )
        self.head = nn.Sequential(
            nn.Conv2d(hidden, hidden, 1), nn.ReLU(), nn.Conv2d(hidden, OUTPUT_CHANNELS, 1)
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = F.relu(self.stem(x))
        for layer in self.context:
            x = x + F.relu(layer(x))
        return self.head(x)


class MultiScaleNet(nn.Module):
    """`compact`'s full-resolution 7×7 colour+position layer, and a context branch at 1/`factor` size.

    Where in a contact a pixel lies (and so how steep its saturated shading really is) needs tens of
    pixels of context; `context` buys it at full resolution. Here the stem's features are average-
    pooled by `factor`, pass residual 3×3 layers dilated 1, 2, 4, 8 (±16 pooled px = ±64 px at
    factor 4), are upsampled bilinearly and join the full-resolution features in a 1×1 head: the
    context costs 1/factor² of its full-resolution price.
    """

    def __init__(
        self, hidden: int = 16, kernel: int = 7, context: int = 24, factor: int = 4, levels: int = 4
    ) -> None:
        super().__init__()
        self.factor = int(factor)
        self.stem = nn.Conv2d(INPUT_CHANNELS, hidden, kernel, padding=kernel // 2)
        self.enter = nn.Conv2d(hidden, context, 3, padding=1)
        self.context = nn.ModuleList(
            nn.Conv2d(context, context, 3, padding=2**i, dilation=2**i) for i in range(levels)
        )
        self.head = nn.Sequential(
            nn.Conv2d(hidden + context, hidden, 1), nn.ReLU(), nn.Conv2d(hidden, OUTPUT_CHANNELS, 1)
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        local = F.relu(self.stem(x))
        c = F.avg_pool2d(local, self.factor, ceil_mode=True)
        c = F.relu(self.enter(c))
        for layer in self.context:
            c = c + F.relu(layer(c))
        c = F.interpolate(c, size=local.shape[-2:], mode="bilinear", align_corners=False)
        return self.head(torch.cat([local, c], 1))


# Preset name → (constructor, keyword arguments stored in the checkpoint).
PIXELNET_ARGS = {
    "compact": {"hidden": 16, "depth": 2, "kernel": 7},
    "compact_tiny": {"hidden": 8, "depth": 2, "kernel": 3},
}
MULTISCALE_ARGS = {"hidden": 16, "kernel": 7, "context": 24, "factor": 4, "levels": 4}
# `context` for frames pooled by 2 (dataset.downscale: 2): half the dilations reach the same
# ±1.7 mm of gel (±17 px at 9.75 px/mm on the DIGIT) at a quarter of the pixels.
CONTEXT_HALF_ARGS = {"hidden": 16, "kernel": 7, "dilations": [1, 2, 4, 8]}


def build_model(preset: str, **overrides) -> nn.Module:
    """A freshly initialised model of `preset` (weights from torch's global RNG: seed it first)."""
    if preset not in PRESET_NAMES:
        raise ConfigError(f"unknown model preset {preset!r} (allowed: {', '.join(PRESET_NAMES)})")
    if preset == "touchnet":
        return TouchNet()
    if preset == "lookup":
        return LookupTable(**overrides)
    if preset == "context":
        return ContextNet(**overrides)
    if preset == "context_half":
        return ContextNet(**{**CONTEXT_HALF_ARGS, **overrides})
    if preset == "multiscale":
        return MultiScaleNet(**{**MULTISCALE_ARGS, **overrides})
    return PixelNet(**{**PIXELNET_ARGS[preset], **overrides})


def preset_args(preset: str) -> dict:
    if preset == "lookup":
        return dict(LOOKUP_DEFAULTS)
    if preset == "multiscale":
        return dict(MULTISCALE_ARGS)
    if preset == "context_half":
        return {**CONTEXT_HALF_ARGS, "dilations": list(CONTEXT_HALF_ARGS["dilations"])}
    return dict(PIXELNET_ARGS.get(preset, {}))


def preferred_memory_format(model: nn.Module) -> torch.memory_format:
    """NHWC for a network with convolutions, NCHW otherwise.

    NHWC lets oneDNN run the 3×3 / 7×7 convolutions without reordering every layer's input: on CPU
    1.2–2× in inference and about 2× per training step of `context`, the same arithmetic up to
    float rounding. A model without convolutions (the lookup table) has nothing to gain."""
    convolutional = any(isinstance(m, nn.Conv2d) for m in model.modules())
    return torch.channels_last if convolutional else torch.contiguous_format


def reach_px(model: nn.Module) -> int | None:
    """How many pixels from an output pixel its value can depend on; None where it is not a window.

    TouchNet, PixelNet and ContextNet are chains (ContextNet residual) of stride-1 'same'
    convolutions and pointwise layers: they reach the sum of their half-kernels, and the lookup
    table is per pixel. `multiscale`'s pooled branch aligns to the whole frame, so a crop would
    change its output: None, as for any network not listed here. Used to score a window of a frame
    without the rest of it.
    """
    if isinstance(model, LookupTable):
        return 0
    if not isinstance(model, TouchNet | PixelNet | ContextNet):
        return None
    reach = 0
    for m in model.modules():
        if isinstance(m, nn.Conv2d):
            half = m.dilation[0] * (m.kernel_size[0] - 1) // 2
            if (
                m.stride != (1, 1)
                or m.padding != (half, half)
                or m.kernel_size[0] != m.kernel_size[1]
            ):
                return None
            reach += half
    return reach


def is_learned(preset: str) -> bool:
    """True for presets trained by gradient descent (lookup is fitted by binning)."""
    return preset != "lookup"
