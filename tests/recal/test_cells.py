"""Recalibration commands on a cell: ``compare`` of two cells (each camera and pair), ``--camera`` elsewhere."""

import json
import shutil

import numpy as np
import pytest

from handeye.cli import main
from handeye.errors import DRIFTED_EXIT_CODE
from handeye.frames import inv_T
from handeye.recal.cells import compare_cells


def _moved_cell(cell, dest, camera="fixed1", dt=(0.005, 0.0, 0.0)):
    """A copy of the cell whose camera ``camera`` (eye-to-hand) moved by ``dt`` metres along the base axes."""
    shutil.copytree(cell["cell"], dest)
    d = json.loads((dest / "result.json").read_text())
    e = d["cameras"][camera]
    T = np.asarray(e["T_base_cam"])
    T[:3, 3] += dt
    e["T_base_cam"] = e["hand_eye"]["matrix"] = T.tolist()
    e["hand_eye"]["translation_mm"] = (1000.0 * T[:3, 3]).tolist()  # a translation: the rotation's forms stay
    for key, p in d["camera_pairs"].items():
        a, b = key.split("/")
        if camera in (a, b):
            Ts = {n: np.asarray(d["cameras"][n][d["cameras"][n]["hand_eye"]["name"]]) for n in (a, b)}
            p["matrix"] = (inv_T(Ts[a]) @ Ts[b]).tolist()
    (dest / "result.json").write_text(json.dumps(d))
    return dest


def test_a_cell_compared_with_itself_is_zero_for_every_camera_and_pair(cell, capsys):
    c = compare_cells(cell["cell"], cell["cell"])
    assert list(c.cameras) == ["wrist", "fixed1", "fixed2"] and list(c.pairs) == ["fixed1/fixed2"]
    for cc in c.cameras.values():
        assert cc.mahalanobis2 == pytest.approx(0.0, abs=1e-12) and cc.p_value == pytest.approx(1.0)
    assert c.pairs["fixed1/fixed2"]["mahalanobis2"] == pytest.approx(0.0, abs=1e-12)
    assert not c.drifted
    assert main(["compare", str(cell["cell"]), str(cell["cell"]), "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["kind"] == "cell" and d["cameras"]["fixed2"]["p_value"] == pytest.approx(1.0) and d["moved"] == []


def test_a_moved_camera_is_named_with_its_pairs_and_the_others_stay(cell, tmp_path, capsys):
    moved = _moved_cell(cell, tmp_path / "moved")
    assert main(["compare", str(cell["cell"]), str(moved)]) == DRIFTED_EXIT_CODE
    out = capsys.readouterr().out
    assert "cell: DRIFTED (fixed1, fixed1/fixed2)" in out
    c = compare_cells(cell["cell"], moved)
    np.testing.assert_allclose(c.cameras["fixed1"].d_trans_mm, [5.0, 0.0, 0.0], atol=1e-9)
    assert c.cameras["fixed1"].p_value < 1e-6 and c.pairs["fixed1/fixed2"]["trans_mm"] == pytest.approx(5.0)
    assert c.cameras["wrist"].mahalanobis2 == pytest.approx(0.0, abs=1e-12) and not c.cameras["fixed2"].drifted


def test_a_cell_against_one_camera_takes_camera_and_names_it(cell, tmp_path, capsys):
    solo = cell["solo"]["fixed2"]
    assert main(["compare", str(solo), str(cell["cell"]), "--camera", "fixed2"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("camera fixed2:\nT_base_cam: B - A") and "Mahalanobis^2 0.00" in out
    assert main(["compare", str(solo), str(cell["cell"])]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "cell of 3 cameras (wrist, fixed1, fixed2)" in err[0] and "--camera NAME" in err[0]
    assert main(["compare", str(solo), str(cell["cell"]), "--camera", "wrist"]) == 2  # another mode: refused
    assert "mounting modes differ" in capsys.readouterr().err
    assert main(["compare", str(cell["cell"]), str(cell["cell"]), "--camera", "fixed1", "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["camera"] == "fixed1" and d["mahalanobis2"] == pytest.approx(0.0, abs=1e-12)
    assert d["results"][0].endswith("result.json (camera fixed1)")
