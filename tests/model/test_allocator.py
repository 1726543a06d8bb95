"""threedcal.model.allocator: freed tensor memory is reused, not page-faulted in again."""

import subprocess
import sys

import pytest

from threedcal.model.allocator import reuse_freed_memory

# Allocates six 8 MB buffers at once and frees them, 20 times (what a training step does with its
# activations), and prints the minor page faults that cost.
CHURN = """
import resource, sys
import numpy as np
if sys.argv[1] == "reuse":
    from threedcal.model.allocator import reuse_freed_memory
    assert reuse_freed_memory()
step = lambda: [np.ones(1 << 21, np.float32) for _ in range(6)]  # 6 x 8 MB, written, then freed
step()  # warm-up: the first touch faults either way
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(20):
    step()
print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""


def faults(mode: str) -> int:
    run = subprocess.run(
        [sys.executable, "-c", CHURN, mode], capture_output=True, text=True, check=True
    )
    return int(run.stdout.strip())


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt")
def test_freed_buffers_are_reused_instead_of_faulted_in_again():
    pages = 20 * 6 * (8 << 20) // 4096  # 245,760: every page of every buffer, faulted again
    assert faults("default") > 0.15 * pages  # glibc hands freed blocks back to the OS (~25 %)
    assert faults("reuse") < 0.01 * pages


def test_the_setting_is_made_once_and_reported():
    first = reuse_freed_memory()
    assert reuse_freed_memory() is first
    assert first == sys.platform.startswith("linux")
