"""Bad input, class "configs": the vendor config.yaml, the site --config and --qa files, and the
command-line numbers. Each case: exit code 2 and the error names the file (or option) and the field."""

from __future__ import annotations

import codecs

import pytest
import yaml

GOOD = {"checkerboard_args": {"XX": 11, "YY": 8, "L": 0.03}}


def _cfg(**cb):
    return yaml.safe_dump({"checkerboard_args": {**GOOD["checkerboard_args"], **cb}})


# (config.yaml text or bytes, culprits)
VENDOR_CONFIG = [
    pytest.param("", ["config.yaml", "checkerboard_args"], id="empty"),
    pytest.param("checkerboard_args: {XX: 11, YY: [8\n", ["config.yaml", "not valid YAML"], id="bad_yaml"),
    pytest.param("- 11\n- 8\n", ["config.yaml", "mapping"], id="a_list"),
    pytest.param("checkerboard_args: 5\n", ["config.yaml", "checkerboard_args"], id="args_a_number"),
    pytest.param(yaml.safe_dump({"checkerboard_args": {"XX": 11, "L": 0.03}}), ["config.yaml", "YY"], id="no_YY"),
    pytest.param(_cfg(XX="eleven"), ["config.yaml", "XX", "'eleven'"], id="XX_text"),
    pytest.param(_cfg(XX=11.5), ["config.yaml", "XX", "11.5"], id="XX_fraction"),
    pytest.param(_cfg(XX=0), ["config.yaml", "XX"], id="XX_zero"),
    pytest.param(_cfg(YY=-8), ["config.yaml", "YY"], id="YY_negative"),
    pytest.param(_cfg(XX=True), ["config.yaml", "XX"], id="XX_bool"),
    pytest.param(_cfg(XX=100000, YY=100000), ["config.yaml", "10000000000 points", "input_limits"], id="huge_board"),
    pytest.param(_cfg(XX=2000, YY=1000), ["config.yaml", "2000000 points"], id="large_board"),
    pytest.param(_cfg(L=30), ["config.yaml", "millimetres"], id="L_millimetres"),
    pytest.param(_cfg(L=0), ["config.yaml", "checkerboard_args.L"], id="L_zero"),
    pytest.param(_cfg(L="3cm"), ["config.yaml", "'3cm'"], id="L_text"),
    pytest.param(_cfg(L=float("nan")), ["config.yaml", "nan"], id="L_nan"),
    pytest.param(_cfg(L=float("inf")), ["config.yaml", "inf"], id="L_inf"),
    pytest.param(_cfg(L=None), ["config.yaml", "None"], id="L_null"),
    pytest.param(_cfg() + "mode: sideways\n", ["config.yaml", "sideways"], id="bad_mode"),
    pytest.param(b"\x00\x01\x02" * 50, ["config.yaml", "UTF-16"], id="binary"),
    pytest.param(
        "checkerboard_args: !!python/object/apply:os.system ['true']\n",
        ["config.yaml", "YAML"],
        id="python_tag_never_runs",
    ),
    pytest.param("a: &a [*a]\n", ["config.yaml"], id="recursive_alias"),
    pytest.param(_cfg() + "recorded: 2026-02-30\n", ["config.yaml", "date", "day is out of range"], id="no_such_day"),
]


@pytest.mark.parametrize("text, culprits", VENDOR_CONFIG)
def test_vendor_config(text, culprits, tiny_vendor, copy_session, run_cli, names, fast_failed_load, tmp_path):
    s = copy_session(tiny_vendor)
    (s / "config.yaml").write_bytes(text if isinstance(text, bytes) else text.encode())
    rc, err = run_cli("calibrate", s, "--out", tmp_path / "out", "--no-report")
    assert rc == 2, err
    names(err, *culprits)


@pytest.mark.parametrize(
    "text",
    [
        pytest.param(("# Schachbrett, Kantenlänge 30 mm\n" + _cfg()).encode("latin-1"), id="latin1"),
        pytest.param(codecs.BOM_UTF8 + _cfg().encode(), id="utf8_bom"),
        pytest.param(_cfg().encode("utf-16"), id="utf16_bom"),
    ],
)
def test_vendor_config_encodings_are_read(text, tiny_vendor, copy_session, run_cli, tmp_path):
    s = copy_session(tiny_vendor)
    (s / "config.yaml").write_bytes(text)
    rc, err = run_cli("calibrate", s, "--out", tmp_path / "out", "--no-report", "--no-refine")
    assert rc in (0, 7), err  # read: 6 views may FAIL the QA, never an input error


# (--config text or bytes, culprits)
SITE_CONFIG = [
    pytest.param("motion: 5\n", ["site.yaml", "'motion'", "a mapping"], id="motion_number"),
    pytest.param("motion: null\n", ["site.yaml", "'motion'", "a mapping"], id="motion_null"),
    pytest.param("min_corners: abc\n", ["site.yaml", "min_corners", "'abc'"], id="min_corners_text"),
    pytest.param("min_corners: 2\n", ["site.yaml", "min_corners"], id="min_corners_too_few"),
    pytest.param("min_corners: 4.5\n", ["site.yaml", "min_corners"], id="min_corners_fraction"),
    pytest.param("refine: maybe\n", ["site.yaml", "'refine'", "true | false"], id="refine_text"),
    pytest.param("fix_k3: 1\n", ["site.yaml", "'fix_k3'"], id="fix_k3_number"),
    pytest.param("method: 3\n", ["site.yaml", "'method'", "a text"], id="method_number"),
    pytest.param("methd: park\n", ["site.yaml", "unknown setting 'methd'"], id="unknown_key"),
    pytest.param("motion: {min_rotation_deg: ten}\n", ["site.yaml", "min_rotation_deg"], id="motion_text"),
    pytest.param("motion: {min_rotation: 10}\n", ["site.yaml", "min_rotation"], id="motion_unknown"),
    pytest.param("motion: {min_rotation_deg: .nan}\n", ["site.yaml", "motion.min_rotation_deg"], id="motion_nan"),
    pytest.param(
        "motion: {min_axis_spread_deg: -5}\n", ["site.yaml", "motion.min_axis_spread_deg"], id="motion_negative"
    ),
    pytest.param("refine_options: {robot_noise: sometimes}\n", ["site.yaml", "robot_noise"], id="robot_noise"),
    pytest.param("refine_options: {robot_sigma_mm: -1}\n", ["site.yaml", "robot_sigma_mm"], id="sigma_negative"),
    pytest.param("refine_options: {outlier_loop: often}\n", ["site.yaml", "outlier_loop"], id="outlier_loop"),
    pytest.param("refine_options: 3\n", ["site.yaml", "refine_options"], id="refine_options_number"),
    pytest.param("[1, 2]\n", ["site.yaml", "mapping"], id="a_list"),
    pytest.param("method: [park\n", ["site.yaml", "not valid YAML"], id="bad_yaml"),
    pytest.param("checked: 2026-01-01T00:00:00+25:00\n", ["site.yaml", "date or time"], id="no_such_offset"),
    pytest.param("method: park\x00\x00\x00\x00\x00\n", ["site.yaml"], id="nul_bytes"),
    pytest.param(("# Genauigkeit\xb1\nmotion: 5\n").encode("latin-1"), ["site.yaml", "'motion'"], id="latin1_read"),
    pytest.param(codecs.BOM_UTF8 + b"motion: 5\n", ["site.yaml", "'motion'"], id="bom_read"),
]


@pytest.mark.parametrize("text, culprits", SITE_CONFIG)
def test_site_config(text, culprits, tiny_vendor, run_cli, names, tmp_path):
    site = tmp_path / "site.yaml"
    site.write_bytes(text if isinstance(text, bytes) else text.encode())
    rc, err = run_cli("calibrate", tiny_vendor, "--config", site, "--out", tmp_path / "out")
    assert rc == 2, err
    names(err, *culprits)
    assert not (tmp_path / "out").exists()  # refused before any work


@pytest.mark.parametrize("what", ["missing", "folder"])
def test_site_config_file_itself(what, tiny_vendor, run_cli, names, tmp_path):
    site = tmp_path / "site.yaml"
    if what == "folder":
        site.mkdir()
    rc, err = run_cli("calibrate", tiny_vendor, "--config", site, "--out", tmp_path / "out")
    assert rc == 2
    names(err, "site.yaml")


QA = [
    pytest.param("crashed_stage: ignore\n", ["qa.yaml", "crashed_stage"], id="crashed_stage"),
    pytest.param("working_distance_m: far\n", ["qa.yaml", "working_distance_m"], id="distance_text"),
    pytest.param("checks: 5\n", ["qa.yaml", "checks"], id="checks_number"),
    pytest.param("nonsense: 1\n", ["qa.yaml", "nonsense"], id="unknown_key"),
    pytest.param("signed: 2026-13-45\n", ["qa.yaml", "month must be in 1..12"], id="no_such_month"),
]


@pytest.mark.parametrize("text, culprits", QA)
def test_site_qa(text, culprits, tiny_vendor, run_cli, names, tmp_path):
    qa = tmp_path / "qa.yaml"
    qa.write_text(text)
    rc, err = run_cli("calibrate", tiny_vendor, "--qa", qa, "--out", tmp_path / "out")
    assert rc == 2, err
    names(err, *culprits)


# command-line numbers and choices: argparse's usage line and one error line naming the option
CLI = [
    pytest.param(["--workers", "-1"], "--workers", id="workers_negative"),
    pytest.param(["--workers", "0"], "--workers", id="workers_zero"),
    pytest.param(["--workers", "two"], "--workers", id="workers_text"),
    pytest.param(["--robot-sigma", "-1", "0.1"], "--robot-sigma", id="sigma_negative"),
    pytest.param(["--robot-sigma", "nan", "0.1"], "--robot-sigma", id="sigma_nan"),
    pytest.param(["--robot-sigma", "1"], "--robot-sigma", id="sigma_one_value"),
    pytest.param(["--shift-poses", "1.5"], "--shift-poses", id="shift_fraction"),
    pytest.param(["--method", "magic"], "--method", id="method_unknown"),
    pytest.param(["--mode", "eye_on_hand"], "--mode", id="mode_unknown"),
    pytest.param(["--fix", "fz"], "--fix", id="fix_unknown"),
]


@pytest.mark.parametrize("argv, option", CLI)
def test_command_line(argv, option, tiny_vendor, run_cli, names, tmp_path):
    rc, err = run_cli("calibrate", tiny_vendor, "--out", tmp_path / "out", *argv)
    assert rc == 2
    names(err, option)
    assert not (tmp_path / "out").exists()


COLLECT = [
    pytest.param(["--speed", "2"], "--speed", id="speed_above_one"),
    pytest.param(["--speed", "nan"], "--speed", id="speed_nan"),
    pytest.param(["--max-speed", "0"], "--max-speed", id="max_speed_zero"),
    pytest.param(["--resolution", "big"], "--resolution", id="resolution_text"),
    pytest.param(["--resolution", "0x0"], "--resolution", id="resolution_zero"),
    pytest.param(["--resolution", "100000x100000"], "--resolution", id="resolution_huge"),
    pytest.param(["--fps", "-30"], "--fps", id="fps_negative"),
    pytest.param(["--timeout", "-1"], "--timeout", id="timeout_negative"),
    pytest.param(["--still-tol", "0.1", "inf"], "--still-tol", id="still_tol_inf"),
    pytest.param(["--plan-pixel-noise", "0"], "--plan-pixel-noise", id="plan_noise_zero"),
    pytest.param(["--auto", "--views", "0"], "--views", id="views_zero"),
    pytest.param(["--target", "hexboard 3x3"], "target", id="target_unknown"),
]


@pytest.mark.parametrize("argv, option", COLLECT)
def test_collect_options(argv, option, run_cli, names, tmp_path):
    rc, err = run_cli(
        "collect", tmp_path / "new", "--mode", "eye_in_hand", "--camera", "sim", "--robot", "sim", "--seed", "1", *argv
    )
    assert rc == 2, err
    names(err, option)
    assert not (tmp_path / "new").exists()  # refused before anything was written


def test_squares_counted_for_inner_corners_are_one_finding_naming_the_size(
    tiny_vendor, copy_session, run_cli, tmp_path
):
    """config.yaml gives the squares (12x9) of an 11x8-corner board. The verdict named the size, but the findings
    were "Only 0 usable views -> capture 10 or more further views" and "found in only 0 of 6 images -> check the
    board size ..., lighting and focus": advice beside the point. One finding names the size to write."""
    import json

    s = copy_session(tiny_vendor)
    (s / "config.yaml").write_text(_cfg(XX=12, YY=9))
    rc, _ = run_cli("calibrate", s, "--out", tmp_path / "o", "--no-report", one_line=False)
    assert rc == 3
    res = json.loads((tmp_path / "o" / "result.json").read_text())
    failing = [f for f in res["findings"] if f["severity"] == "fail"]
    assert [f["code"] for f in failing] == ["target_not_found"], failing
    f = failing[0]
    assert f["title"] == "The board has 11x8 inner corners, not 12x9 as stated: the target was found in 0 of 6 images"
    assert f["action"].startswith("the board has 11x8 inner corners, not 12x9: fix config.yaml checkerboard_args")
    assert res["diagnostics"]["findings"][0]["details"] == {"board_size": [11, 8]}
