"""The host a figure was measured on, as benchmarks and environment.json name it."""

from threedcal.model.machine import cpu_capability, cpu_flags, host_line, isa_limits
from threedcal.report.summary import environment


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
