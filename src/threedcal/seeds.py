"""The seed each replicate of a study draws with: its subsets, its model's initialisation and
patches, a quick calibration's run r. Below every package, so collection and training share it."""

from __future__ import annotations

import numpy as np

from threedcal.errors import ConfigError


def replicate_seed(seed: int, replicate: int) -> int:
    """The seed of replicate r: the scene's own for r = 0, SeedSequence([seed, r])'s first word after.

    Used for replicate r's subset draw and for its model's initialisation and patch sampling.
    """
    if replicate < 0:
        raise ConfigError(f"replicate must be 0 or more, got {replicate}")
    if replicate == 0:
        return int(seed)
    return int(np.random.SeedSequence([int(seed), int(replicate)]).generate_state(1)[0])
