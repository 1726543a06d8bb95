"""The host a figure was measured on, as benchmarks and environment.json name it."""

import pytest
import torch
from test_model import TINY, fresh_checkpoint, synthetic_set

from threedcal.errors import ConfigError
from threedcal.model.inference import DepthEstimator
from threedcal.model.machine import cpu_capability, cpu_flags, host_line, isa_limits, torch_device
from threedcal.model.train import TrainSettings, train
from threedcal.report.environment import environment


def test_an_emulated_avx2_machine_says_so(monkeypatch):
    for name in (
        "ONEDNN_MAX_CPU_ISA",
        "DNNL_MAX_CPU_ISA",
        "ATEN_CPU_CAPABILITY",
        "OPENBLAS_CORETYPE",
    ):
        monkeypatch.delenv(name, raising=False)
    assert isa_limits() == {}
    assert "limited by" not in host_line()
    monkeypatch.setenv("ONEDNN_MAX_CPU_ISA", "AVX2")
    monkeypatch.setenv("OPENBLAS_CORETYPE", "Haswell")
    assert isa_limits() == {"ONEDNN_MAX_CPU_ISA": "AVX2", "OPENBLAS_CORETYPE": "Haswell"}
    line = host_line()
    assert "limited by ONEDNN_MAX_CPU_ISA=AVX2, OPENBLAS_CORETYPE=Haswell" in line
    assert f"torch dispatches {cpu_capability()}" in line


def test_the_run_environment_names_the_cpu_and_its_vector_instructions(monkeypatch):
    monkeypatch.setenv("ATEN_CPU_CAPABILITY", "avx2")
    record = environment({"seed": 0, "torch_threads": 1, "scenes": {}})
    name, flags = cpu_flags()
    assert record["cpu"] == name and record["cpu_flags"] == " ".join(flags)
    assert record["isa_limits"] == "ATEN_CPU_CAPABILITY=avx2"
    assert record["torch_cpu_capability"] == cpu_capability()
    assert all(f.startswith(("avx", "fma", "amx")) for f in flags)


def test_a_device_torch_cannot_reach_is_refused_naming_the_setting(tmp_path):
    """Before any training or inference starts (a raw torch assertion ended a training after its
    collection): a device type torch does not know, and a CUDA device this torch cannot reach."""
    with pytest.raises(ConfigError, match=r"^model\.device: 'gpu' is no torch device"):
        torch_device("gpu")
    missing = "cuda:99" if torch.cuda.is_available() else "cuda"
    with pytest.raises(ConfigError, match=rf"^model\.device: '{missing}', but torch"):
        torch_device(missing)
    settings = TrainSettings.of(preset="compact_tiny", device=missing, **TINY)
    with pytest.raises(ConfigError, match="model.device"):
        train(synthetic_set(), tmp_path / "m", 80, settings, progress=False)
    assert not (tmp_path / "m" / "model.pt").exists()
    checkpoint = fresh_checkpoint("compact_tiny", synthetic_set(), seed=0)
    with pytest.raises(ConfigError, match=rf"^device: '{missing}', but torch"):
        DepthEstimator(checkpoint, device=missing)
    assert torch_device("cpu") == torch.device("cpu")
    expected = "cuda" if torch.cuda.is_available() else "cpu"
    assert torch_device("auto").type == torch_device(None).type == expected
