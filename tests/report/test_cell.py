"""``handeye report`` on a cell: a table of its cameras and one of its camera pairs, HTML and Markdown."""

import html
import shutil

import numpy as np

from handeye.cli import main
from handeye.contract import read_result


def test_a_cell_folder_gets_a_report_of_its_cameras_and_pairs(cell, tmp_path, capsys):
    folder = tmp_path / "cell"
    shutil.copytree(cell["cell"], folder)
    assert main(["report", str(folder)]) == 0
    md = (folder / "report.md").read_text()
    page = html.unescape((folder / "report.html").read_text())
    res = read_result(folder)
    for name in res.camera_names:
        one = res.camera_result(name)
        t = " ".join(f"{v:.2f}" for v in 1000.0 * one.T_x[:3, 3])
        row = next(line for line in md.splitlines() if line.startswith(f"| {name} |"))
        assert f"| {one.mode} | {one.x_name} | {t} |" in row and row.endswith(f"| {one.verdict} |")
        assert t in page and name in page
    pair = res.raw["camera_pairs"]["fixed1/fixed2"]
    d = 1000.0 * np.linalg.norm(np.asarray(pair["matrix"])[:3, 3])
    prow = next(line for line in md.splitlines() if line.startswith("| fixed1/fixed2 |"))
    assert "T_fixed1_fixed2" in prow and f"| {d:.2f} |" in prow
    R = np.asarray(pair["matrix"])[:3, :3]  # the translation's 1-sigma of T_a_b along camera a's axes
    s_t = 1000.0 * np.sqrt(np.diag(R @ np.asarray(pair["cov_6x6"])[3:, 3:] @ R.T))
    assert " ".join(f"{v:.3f}" for v in s_t) in prow
    assert "**Verdict: WARN**" in md and "Verdict: WARN" in page
