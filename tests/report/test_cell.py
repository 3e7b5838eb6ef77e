"""``handeye report`` on a cell's folder: the cell's report (handeye.cell.report), never a one-camera misreading."""

import html
import shutil

import numpy as np
import pytest

from handeye.cli import main
from handeye.contract import read_result
from handeye.errors import InputError


def test_handeye_report_on_a_cell_writes_the_cells_report(cell, tmp_path, capsys):
    folder = tmp_path / "cell"
    shutil.copytree(cell["cell"], folder)
    assert main(["report", str(folder)]) == 0
    md = (folder / "report.md").read_text()
    page = html.unescape((folder / "report.html").read_text())
    res = read_result(folder)
    from handeye.frames import rotvec_from_R

    for name in res.camera_names:  # X whole: its translation and its rotation, named, the mode in words
        one = res.camera_result(name)
        t = " ".join(f"{v:.2f}" for v in 1000.0 * one.T_x[:3, 3])
        r = " ".join(f"{v:.3f}" for v in np.degrees(rotvec_from_R(one.T_x[:3, :3])))
        row = next(line for line in md.splitlines() if line.startswith(f"| {name} |"))
        assert row.startswith(f"| {name} | {one.mode.replace('_', '-')} | {one.verdict} | {one.x_name} | {t} | {r} |")
        assert t in page and r in page
    pair = res.raw["camera_pairs"]["fixed1/fixed2"]
    prow = next(line for line in md.splitlines() if line.startswith("| T_fixed1_fixed2 |"))
    T = np.asarray(pair["matrix"])
    assert " ".join(f"{v:.2f}" for v in pair["translation_mm"]) in prow
    assert " ".join(f"{v:.3f}" for v in np.degrees(rotvec_from_R(T[:3, :3]))) in prow  # the pair's rotation too
    from handeye.cell.report import cell_markdown

    prov = {"handeye_version": "9.9", "command_line": "handeye calibrate a b", "time_utc": "2026-12-07T10:00:00+00:00"}
    head = cell_markdown({**res.raw, "provenance": prov}).splitlines()[:5]  # when, by which version and command
    assert head[2:5] == ["Calibrated 2026-12-07 10:00:00 UTC · handeye 9.9", "", "Command: `handeye calibrate a b`"]
    assert main(["report", str(folder), "--format", "md", "--out", str(tmp_path / "md")]) == 0
    assert [p.name for p in (tmp_path / "md").iterdir()] == ["report.md"]


def test_the_one_camera_report_refuses_a_cell_in_one_line(cell):
    from handeye.report import write_reports

    with pytest.raises(InputError, match="cell of several cameras") as e:
        write_reports(cell["cell"])
    assert "\n" not in str(e.value)
