"""The classic GelSight calibration: a colour → gradient lookup table, the baseline to beat.

Each pixel's colour change ΔRGB (and, coarsely, its position on the gel, since the lighting varies
across it) is binned; a bin holds the mean gradient label of the training pixels that fell in it.
Bins no training pixel reached take the value of the nearest filled bin (Euclidean in bin space).
"""

from __future__ import annotations

import numpy as np
import torch
from scipy import ndimage
from torch import nn

LOOKUP_DEFAULTS = {"rgb_bins": 24, "pos_bins": 3}
# ΔRGB range of the table: these quantiles of the training pixels (the rest clamp to the end bins).
RANGE_QUANTILES = (0.0005, 0.9995)


class LookupTable(nn.Module):
    def __init__(self, rgb_bins: int = 24, pos_bins: int = 3) -> None:
        super().__init__()
        self.rgb_bins, self.pos_bins = int(rgb_bins), int(pos_bins)
        shape = (self.pos_bins, self.pos_bins, self.rgb_bins, self.rgb_bins, self.rgb_bins, 2)
        self.register_buffer("table", torch.zeros(shape))
        self.register_buffer("low", torch.full((3,), -1.0))
        self.register_buffer("high", torch.full((3,), 1.0))

    def bin_index(self, x: torch.Tensor) -> torch.Tensor:
        """(N, H, W) flat table index of every pixel of a (N, 5, H, W) input."""
        b, p = self.rgb_bins, self.pos_bins
        scale = (b / (self.high - self.low)).view(1, 3, 1, 1)
        rgb = ((x[:, :3] - self.low.view(1, 3, 1, 1)) * scale).floor().long().clamp_(0, b - 1)
        pos = ((x[:, 3:5] + 1.0) * (p / 2.0)).floor().long().clamp_(0, p - 1)
        cell = pos[:, 1] * p + pos[:, 0]  # row-major over (y, x) position cells
        return ((cell * b + rgb[:, 0]) * b + rgb[:, 1]) * b + rgb[:, 2]

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        flat = self.bin_index(x)
        return self.table.view(-1, 2)[flat].permute(0, 3, 1, 2).contiguous()

    @torch.no_grad()
    def fit(self, pairs) -> None:
        """Fill the table from a re-iterable of (inputs (5,H,W), labels (2,H,W)) numpy pairs."""
        sample = np.concatenate([x[:3].reshape(3, -1)[:, ::7] for x, _ in pairs], axis=1)
        low, high = np.quantile(sample, RANGE_QUANTILES, axis=1)
        high = np.maximum(high, low + 1e-3)
        self.low.copy_(torch.from_numpy(low.astype(np.float32)))
        self.high.copy_(torch.from_numpy(high.astype(np.float32)))
        n_bins = self.table[..., 0].numel()
        sums = np.zeros((n_bins, 2))
        counts = np.zeros(n_bins)
        for x, y in pairs:
            inputs = torch.from_numpy(np.ascontiguousarray(x))[None].to(self.low.device)
            flat = self.bin_index(inputs).cpu().numpy().ravel()
            counts += np.bincount(flat, minlength=n_bins)
            for c in range(2):
                sums[:, c] += np.bincount(flat, weights=y[c].ravel(), minlength=n_bins)
        cells = self.pos_bins**2
        rgb_shape = (self.rgb_bins,) * 3
        sums = sums.reshape(cells, *rgb_shape, 2)
        counts = counts.reshape(cells, *rgb_shape)
        pooled = _nearest_fill(sums.sum(0), counts.sum(0))
        table = np.stack(
            [_nearest_fill(sums[c], counts[c]) if counts[c].any() else pooled for c in range(cells)]
        )
        self.table.copy_(torch.from_numpy(table.reshape(self.table.shape).astype(np.float32)))


def _nearest_fill(sums: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Mean label per bin; empty bins copy their nearest filled bin (all-zero if none is filled)."""
    if not counts.any():
        return np.zeros(sums.shape)
    mean = sums / np.maximum(counts, 1)[..., None]
    _, nearest = ndimage.distance_transform_edt(counts == 0, return_indices=True)
    return mean[tuple(nearest)]
