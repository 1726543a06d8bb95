"""The stage-time table: benchmark files summed per stage, against hand-written files."""

import pandas as pd
import pytest

from threedcal.report.stage_times import stage_of, stage_time_lines, stage_times

HEADER = "s\th:m:s\tmax_rss\tmax_vms\tmax_uss\tmax_pss\tio_in\tio_out\tmean_load\tcpu_time\n"


def bench(path, wall, rss, cpu, rerun=None):
    path.parent.mkdir(parents=True, exist_ok=True)
    text = HEADER + f"{wall}\t0:00:00\t{rss}\t0\t0\t0\t0\t0\t0\t{cpu}\n"
    if rerun:
        text += f"{rerun[0]}\t0:00:00\t{rerun[1]}\t0\t0\t0\t0\t0\t0\t{rerun[2]}\n"
    path.write_text(text)


@pytest.mark.parametrize(
    ("name", "stage"),
    [
        ("train_P20_r0.tsv", "train"),
        ("train_ablation_P20.tsv", "train_ablation"),
        ("cv_model_fold3.tsv", "cv_model"),
        ("cv_train_fold3.tsv", "cv_train"),
        ("sim2real_shipped_real_fold1.tsv", "sim2real_shipped_real"),
        ("sim2real_pretrain_folds0-1-2.tsv", "sim2real_pretrain"),
        ("sim2real_simulate_folds4.tsv", "sim2real_simulate"),
        ("sim2real_real_only_kall_fold0.tsv", "sim2real_real_only"),
        ("sim2real_sim_real_k8_fold2.tsv", "sim2real_sim_real"),
        ("dataset_collected.tsv", "dataset_collected"),
    ],
)
def test_a_jobs_file_names_its_stage(tmp_path, name, stage):
    assert stage_of(tmp_path / name) == stage


def test_jobs_of_a_stage_add_up_per_scene_longest_first(tmp_path):
    results = tmp_path / "results"
    bench(results / "a/benchmarks/train_P20_r0.tsv", 100.0, 500.0, 180.0)
    bench(results / "a/benchmarks/train_P80_r1.tsv", 50.0, 700.0, 90.0)
    bench(results / "b/benchmarks/train_P20_r0.tsv", 30.0, 400.0, 50.0)
    # a rerun appends a line: the last one is the job that made today's outputs
    bench(results / "a/benchmarks/collect.tsv", 999.0, 100.0, 9.0, rerun=(20.0, 110.0, 5.0))
    bench(results / "benchmarks/summary.tsv", 2.0, 90.0, 1.0)
    table = stage_times(results)
    assert table[["stage", "scene"]].values.tolist() == [
        ["train", "a"],
        ["train", "b"],
        ["collect", "a"],
        ["summary", ""],
    ]
    first = table.iloc[0]
    assert (first["jobs"], first["wall_s"], first["cpu_s"]) == (2, 150.0, 270.0)
    assert (first["longest_job_s"], first["max_rss_mb"]) == (100.0, 700.0)
    assert table.iloc[2]["wall_s"] == 20.0
    lines = stage_time_lines(table, limit=2)
    assert lines[2] == "| train | a | 2 | 2.5 | 74 % | 4.5 | 1.7 | 700 |"
    assert lines[4].startswith("| 2 other stages | — | 2 | 0.4 | 11 % |")
    assert lines[-1] == "| **all** | | 5 | 3.4 | 100 % | 5.4 | | |"


def test_no_benchmark_files_is_said_not_hidden(tmp_path):
    table = stage_times(tmp_path)
    assert table.empty and list(table.columns)[:2] == ["stage", "scene"]
    assert stage_time_lines(table) == ["No benchmark files yet."]
    assert isinstance(table, pd.DataFrame)
