"""The one reader and writer of result.json: damaged fields through every command that reads a result, the
version rule, the typed accessors, and the writer that refuses what it could not read back."""

import json

import numpy as np
import pytest

import handeye.contract as contract
from handeye.cli import main
from handeye.contract import read_result, validate_result, write_result
from handeye.errors import InputError


def _damage(folder, change):
    p = folder / "result.json"
    d = json.loads(p.read_text())
    change(d)
    p.write_text(json.dumps(d))
    return folder


def _zero_covariances(d):
    d["refinement"]["cov_x_6x6"] = [[0.0] * 6 for _ in range(6)]
    d["refinement"]["cov_x_6x6_verdict"] = [[0.0] * 6 for _ in range(6)]


DAMAGES = [
    pytest.param(_zero_covariances, "refinement.cov_x_6x6", "all zeros", id="zero_covariance"),
    pytest.param(lambda d: d["intrinsics"]["dist"].__setitem__("k1", "abc"), "intrinsics.dist.k1", "'abc'", id="k1"),
    pytest.param(
        lambda d: d["intrinsics"].__setitem__("image_size", ["w", "h"]),
        "intrinsics.image_size",
        "['w', 'h']",
        id="image_size",
    ),
    pytest.param(
        lambda d: d["refinement"].__setitem__("intrinsics_sigma", [0.5, 0.5]),
        "refinement.intrinsics_sigma",
        "[0.5, 0.5]",
        id="intrinsics_sigma_list",
    ),
]


def _commands(results, bad, tmp_path):
    session = results["images"].parent / "images_s"
    end_pose = ["--end-pose", "0.5", "0", "0.5", "3.1", "0", "0"]
    return {
        "verify": ["verify", session, "--against", bad, "--out", tmp_path / "v"],
        "compare": ["compare", results["images"], bad],
        "compare_second": ["compare", bad, results["images"]],
        "report": ["report", bad, "--out", tmp_path / "r"],
        "export": ["export", bad, "--to", "json", "--out", tmp_path / "x.json"],
        "apply": ["apply", bad, "--point", "0", "0", "0.5", *end_pose],
        "calibrate_prior": ["calibrate", session, "--prior", bad, "--out", tmp_path / "c", "--no-report"],
    }


@pytest.mark.parametrize("damage, field, got", DAMAGES)
def test_a_damaged_field_is_one_line_naming_it_from_every_command(
    damage, field, got, results, copy_result, tmp_path, capsys
):
    """Each of these gave exit 1 ("internal error ... this is a bug") from verify and compare; a prior whose
    covariance is broken is named as the prior file's field."""
    bad = _damage(copy_result("images"), damage)
    for name, argv in _commands(results, bad, tmp_path).items():
        capsys.readouterr()
        rc = main(["-q", *map(str, argv)])
        err = capsys.readouterr().err.strip().splitlines()
        assert rc == 2, (name, err)
        assert len(err) == 1 and "Traceback" not in err[0], (name, err)
        assert str(bad / "result.json") in err[0] and f"damaged: {field}" in err[0] and got in err[0], (name, err)
    assert not (tmp_path / "x.json").exists() and not (tmp_path / "v").exists()
    assert not (tmp_path / "c" / "result.json").exists()


def test_the_reader_names_file_field_expected_and_received(copy_result):
    bad = _damage(copy_result("images"), lambda d: d["intrinsics"]["dist"].__setitem__("k1", "abc"))
    with pytest.raises(InputError) as e:
        read_result(bad)
    assert e.value.code == "result_damaged" and e.value.path == str(bad / "result.json")
    assert (e.value.what, e.value.expected, e.value.received) == (
        "damaged: intrinsics.dist.k1 is 'abc'",
        "a finite number",
        None,
    )


@pytest.mark.parametrize(
    "change, words",
    [
        (lambda d: d.__setitem__("status", "ok") or d.__setitem__("mode", "sideways"), ["mode", "'sideways'"]),
        (lambda d: d["refinement"]["cov_x_6x6"][0].__setitem__(1, 1.0), ["refinement.cov_x_6x6", "not symmetric"]),
        (lambda d: d["refinement"]["cov_x_6x6"][0].__setitem__(0, -1.0), ["refinement.cov_x_6x6", "positive definite"]),
        (lambda d: d["refinement"].__setitem__("sigma_px", -0.3), ["refinement.sigma_px", ">= 0"]),
        (lambda d: d["intrinsics"].__setitem__("fx", 0), ["intrinsics.fx", "> 0"]),
        (lambda d: d["intrinsics"].__setitem__("fx", 10**400), ["intrinsics.fx", "too large"]),
        (lambda d: d["intrinsics"].__setitem__("image_size", [640, 0]), ["intrinsics.image_size"]),
        (lambda d: d["intrinsics"].__setitem__("image_size", [640.0, 480.0]), ["intrinsics.image_size"]),
        (lambda d: d["T_end_cam"][0].__setitem__(0, 2.0), ["T_end_cam", "rigid"]),
        (lambda d: d["T_end_cam"][1].__setitem__(2, "0"), ["T_end_cam", "4x4"]),
        (lambda d: d.pop("T_end_cam"), ["T_end_cam", "is missing"]),
        (lambda d: d["hand_eye"].__setitem__("name", "T_base_cam"), ["hand_eye.name", "T_end_cam"]),
        (lambda d: d["T_end_cam"][0].__setitem__(3, d["T_end_cam"][0][3] + 0.01), ["hand_eye.matrix", "differs"]),
        (lambda d: d["hand_eye"]["translation_mm"].__setitem__(0, 5.0), ["hand_eye.translation_mm", "differs"]),
        (lambda d: d["T_base_board"][2].__setitem__(3, 9.0), ["board.matrix", "T_base_board"]),
        (lambda d: d["n_views"].__setitem__("used", 99), ["n_views.used", "at most total"]),
        (lambda d: d.__setitem__("verdict", {"PASS": True}), ["verdict", "'PASS'"]),
        (lambda d: d.__setitem__("verdict", "pass"), ["verdict"]),
        (lambda d: d["views"][2].__setitem__("used", 1), ["views[2].used"]),
        (lambda d: d["refinement"]["cov_x_intrinsics"]["cross_6xk"].pop(), ["refinement.cov_x_intrinsics.cross_6xk"]),
        (lambda d: d["refinement"]["intrinsics_sigma"].__setitem__("fx", "0.1"), ["refinement.intrinsics_sigma.fx"]),
        (
            lambda d: d["refinement"]["intrinsics_sigma"].__setitem__("focal", 0.1),
            ["refinement.intrinsics_sigma.focal"],
        ),
    ],
)
def test_meaning_and_range_are_checked(change, words, copy_result):
    bad = _damage(copy_result("images"), change)
    with pytest.raises(InputError) as e:
        read_result(bad)
    for w in words:
        assert w in str(e.value), str(e.value)
    assert len(str(e.value).splitlines()) == 1


def test_unknown_fields_are_kept_and_known_ones_typed(results, copy_result):
    folder = _damage(copy_result("images"), lambda d: d.update(written_by_a_newer_handeye={"x": [1, 2]}))
    m = read_result(folder)
    d = json.loads((folder / "result.json").read_text())
    assert m.raw["written_by_a_newer_handeye"] == {"x": [1, 2]}
    assert m.ok and m.mode == "eye_in_hand" and m.x_name == "T_end_cam" and m.board_name == "T_base_board"
    np.testing.assert_array_equal(m.T_x, np.asarray(d["T_end_cam"]))
    np.testing.assert_array_equal(m.T_board, np.asarray(d["T_base_board"]))
    cov, key = m.cov_x
    assert key == "cov_x_6x6_verdict"
    np.testing.assert_allclose(cov, np.asarray(d["refinement"]["cov_x_6x6_verdict"]), rtol=0, atol=1e-20)
    assert m.camera.fx == d["intrinsics"]["fx"] and (m.camera.width, m.camera.height) == (400, 300)
    assert m.camera.dist[0] == d["intrinsics"]["dist"]["k1"]
    assert m.intrinsics_sigma["fx"] == d["refinement"]["intrinsics_sigma_verdict"]["fx"]
    assert m.verdict == d["verdict"]


def test_failed_and_pose_only_results_read(results):
    for name in ("failed", "unreadable"):
        m = read_result(results[name])
        assert not m.ok and m.T_x is None and m.cov_x == (None, "none") and m.camera is None
    m = read_result(results["pose_only"])
    assert m.ok and m.x_name == "T_base_cam" and m.camera is None and m.cov_x[1] == "cov_x_6x6_verdict"


# ------------------------------------------------------------------------------ versions
@pytest.mark.parametrize(
    "version, words",
    [
        (2, ["version 2 is newer", "upgrade handeye"]),
        (0, ["version 0 is older", "calibrate the session again"]),
        ("1", ["handeye_result", "'1'"]),
        (True, ["handeye_result", "True"]),
    ],
)
def test_other_versions_are_refused_in_one_line(version, words, copy_result, capsys):
    bad = _damage(copy_result("images"), lambda d: d.__setitem__("handeye_result", version))
    with pytest.raises(InputError) as e:
        read_result(bad)
    for w in words:
        assert w in str(e.value)
    rc = main(["-q", "compare", str(bad), str(bad)])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and words[0] in err[0]


def test_a_file_without_the_version_key_is_not_a_result(copy_result):
    bad = _damage(copy_result("images"), lambda d: d.pop("handeye_result"))
    with pytest.raises(InputError, match="not a handeye result.json"):
        read_result(bad)


def test_an_older_version_with_a_migration_is_migrated(copy_result, monkeypatch):
    """The rule for the next version: a known change of an older file is applied, step by step."""

    def v1_to_v2(d):
        d["hand_eye"] = dict(d["hand_eye"], frame_doc=d.pop("frames"))
        return d

    monkeypatch.setattr(contract, "RESULT_VERSION", 2)
    monkeypatch.setitem(contract.MIGRATIONS, 1, v1_to_v2)
    m = read_result(copy_result("images"))
    assert m.raw["handeye_result"] == 2 and "frames" not in m.raw and "T_end_cam" in m.raw["hand_eye"]["frame_doc"]
    monkeypatch.delitem(contract.MIGRATIONS, 1)
    with pytest.raises(InputError, match="version 1 has no migration to version 2"):
        read_result(copy_result("pose_only"))


# ------------------------------------------------------------------------------ the writer
def test_the_writer_refuses_what_it_could_not_read_back(results, tmp_path):
    d = json.loads((results["images"] / "result.json").read_text())
    assert write_result(tmp_path / "result.json", d).is_file()
    assert read_result(tmp_path).raw == d
    d["intrinsics"]["fx"] = np.float64("nan")
    with pytest.raises(ValueError, match="invalid result.json: .*intrinsics.fx"):
        write_result(tmp_path / "bad" / "result.json", d)
    assert not (tmp_path / "bad" / "result.json").exists()


def test_a_partial_dict_is_checked_for_what_it_holds():
    """A program's dict (recal.loaded.result_from_refinement's) may lack parts a file must hold."""
    m = validate_result({"status": "ok", "mode": "eye_to_hand"}, require_version=False)
    assert m.ok and m.T_x is None and m.x_name == "T_base_cam"
    with pytest.raises(InputError, match="T_base_cam"):
        validate_result({"status": "ok", "mode": "eye_to_hand", "T_base_cam": [[1, 0]]}, require_version=False)
    with pytest.raises(InputError, match="T_base_cam is missing"):
        validate_result({"handeye_result": 1, "status": "ok", "mode": "eye_to_hand"})


def test_the_fleet_index_lists_a_damaged_result_as_a_row(results, tmp_path):
    """A result.json whose verdict is a mapping made every later index crash (TypeError)."""
    import shutil

    from handeye.batch.index import read_fleet_csv, write_index

    shutil.copytree(results["images"], tmp_path / "cell" / "good")
    bad = tmp_path / "cell" / "bad"
    shutil.copytree(results["images"], bad)
    _damage(bad, lambda d: d.__setitem__("verdict", {"PASS": True}))
    write_index(tmp_path, plots=False)
    rows = {r["session"]: r for r in read_fleet_csv(tmp_path / "fleet.csv")}
    assert rows["good"]["verdict"] in ("PASS", "WARN")
    assert rows["bad"]["verdict"] == "ERROR" and "verdict is a mapping ({'PASS': True})" in rows["bad"]["reason"]
    assert (tmp_path / "index.html").is_file()


def test_rows_of_numbers_pass_whole_and_name_the_first_that_is_not_a_number():
    """A view's corner residuals: plain JSON numbers (NaN and infinities included) pass in one pass; anything
    else is named by the check of each number."""
    import math

    from pydantic_core import PydanticCustomError

    from handeye.contract.fields import _number_rows

    ok = [[1.0, 2], [math.nan, -math.inf], []]
    assert _number_rows(ok) is ok
    for bad, words in [
        ([[1.0, "x"]], "is 'x'"),
        ([[True, 1.0]], "is True"),
        ([1.0], "holds 1.0"),
        ("abc", "is 'abc'"),
        ([[10**400]], "too large for a float"),
    ]:
        with pytest.raises(PydanticCustomError, match=words):
            _number_rows(bad)
