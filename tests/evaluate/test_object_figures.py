"""Figures and Table II of the test-object evaluation, and `threedcal objects export`."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from threedcal.cli import main
from threedcal.errors import ConfigError
from threedcal.evaluate.mesh import read_mesh, write_stl
from threedcal.evaluate.object_errors import pixel_errors_um
from threedcal.evaluate.object_figures import (
    plot_depth_sections,
    plot_error_violins,
    table_ii_markdown,
)
from threedcal.evaluate.objects import make_object

PNG = b"\x89PNG"


def test_violins_and_sections_write_pngs(tmp_path):
    rng = np.random.default_rng(0)
    gt = np.zeros((40, 50))
    gt[10:30, 15:35] = 0.5
    pred = gt + rng.normal(0, 0.02, gt.shape)
    table = pd.concat([pixel_errors_um(name, pred, gt) for name in ("pill", "pawn")])
    out = plot_error_violins(table, tmp_path / "violins.png", title="test")
    assert out.read_bytes()[:4] == PNG
    out = plot_depth_sections(pred, gt, tmp_path / "sections.png", px_per_mm=19.5)
    assert out.read_bytes()[:4] == PNG
    with pytest.raises(ConfigError, match="outside"):
        plot_depth_sections(pred, gt, tmp_path / "x.png", px_per_mm=19.5, row=99)
    with pytest.raises(ConfigError, match="columns"):
        plot_error_violins(table.drop(columns="type"), tmp_path / "y.png")


def test_table_ii_markdown():
    rows = pd.DataFrame(
        [
            ("digit_sim", "pill", 80, 30.0, 10.0, 60.4),
            ("digit_sim", "pill", 20, 99.0, 99.0, 99.0),
            ("mini_sim", "pill", 80, 40.0, 20.0, 80.0),
            ("digit_sim", "pawn", 80, 50.0, 20.0, 150.0),
        ],
        columns=["scene", "object", "P", "overall_um", "type1_um", "type2_um"],
    )
    text = table_ii_markdown(rows)
    lines = text.strip().splitlines()
    assert lines[2].startswith("| object | digit_sim overall | digit_sim Type 1 | digit_sim Type 2")
    assert "| pill | 30 | 10 | 60 | 40 | 20 | 80 |" in lines
    assert "| pawn | 50 | 20 | 150 | — | — | — |" in lines
    with pytest.raises(ConfigError, match="P = 50"):
        table_ii_markdown(rows, p=50)
    # with a protocol column: the printer protocol unless asked, and the table says which
    both = pd.concat([rows.assign(protocol="printer"), rows.assign(protocol="paper", type2_um=1.0)])
    text = table_ii_markdown(both)
    assert "printer protocol" in text and "| pill | 30 | 10 | 60 | 40 | 20 | 80 |" in text
    assert "| pill | 30 | 10 | 1 | 40 | 20 | 1 |" in table_ii_markdown(both, protocol="paper")


def test_cli_export_writes_printable_stls(tmp_path, capsys):
    assert main(["objects", "export", "--out", str(tmp_path), "--objects", "pill", "pawn"]) == 0
    for name in ("pill", "pawn"):
        assert read_mesh(tmp_path / f"{name}.stl").is_watertight()
        assert (tmp_path / f"{name}_depth.png").read_bytes()[:4] == PNG
    assert "watertight=True" in capsys.readouterr().out
    assert main(["objects", "export", "--out", str(tmp_path / "x"), "--objects", "rook"]) == 1
    assert not (tmp_path / "x").exists()


def test_cli_export_never_replaces_files_and_never_exports_an_stl_onto_itself(tmp_path, capsys):
    """Repro: a second export into the same folder replaced the first without a word, and the
    README's `--objects stl/pill.stl --out stl/` replaced the user's own STL with its re-centred
    copy."""
    out = tmp_path / "stl"
    assert main(["objects", "export", "--out", str(out), "--objects", "pill", "pawn"]) == 0
    capsys.readouterr()
    preview = (out / "pawn_depth.png").read_bytes()
    again = ["objects", "export", "--out", str(out), "--objects", "pill", "pawn"]
    assert main([*again, "--indentation-mm", "1.5"]) == 1
    assert "pill.stl: already exists; refusing to overwrite it" in capsys.readouterr().err
    assert (out / "pawn_depth.png").read_bytes() == preview
    assert main([*again, "--indentation-mm", "1.5", "--force"]) == 0
    assert (out / "pawn_depth.png").read_bytes() != preview
    mine = out / "pill.stl"
    before = mine.read_bytes()
    for extra in ([], ["--force"]):
        assert main(["objects", "export", "--out", str(out), "--objects", str(mine), *extra]) == 1
        assert "is the --objects file" in capsys.readouterr().err
        assert mine.read_bytes() == before
    assert (
        main(["objects", "export", "--out", str(tmp_path / "check"), "--objects", str(mine)]) == 0
    )


def test_cli_export_refuses_two_objects_of_one_name(tmp_path, capsys):
    """Repro: `--objects pill a/pill.stl` wrote one pill.stl (the user's file, re-centred) and
    dropped the built-in pill without a word."""
    mine = tmp_path / "a" / "pill.stl"
    mine.parent.mkdir()
    write_stl(make_object("pawn"), mine)
    out = tmp_path / "out"
    assert main(["objects", "export", "--out", str(out), "--objects", "pill", str(mine)]) == 1
    err = capsys.readouterr().err
    assert "more than one object is named 'pill'" in err and str(mine) in err
    assert not out.exists()
