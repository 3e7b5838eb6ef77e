"""Bad input, class "pose text": poses.txt of a vendor session written wrongly (format, numbers,
units, encodings, counts). Each case: exit code 2 and the error names poses.txt (and the line)."""

from __future__ import annotations

import codecs

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st


def _lines(text: str) -> list[str]:
    return [ln for ln in text.splitlines() if ln.strip()]


def _set_line(k: int, new: str):
    def f(text):
        lines = _lines(text)
        lines[k] = new
        return "\n".join(lines) + "\n"

    return f


def _field(k: int, j: int, value: str):
    def f(text):
        lines = _lines(text)
        parts = lines[k].split(",")
        parts[j] = value
        lines[k] = ",".join(parts)
        return "\n".join(lines) + "\n"

    return f


def _encode(enc: str, bom: bytes = b""):
    return lambda text: bom + text.encode(enc)


# (edit of the text (str -> str or bytes), exit code, culprits the error names)
CASES = [
    pytest.param(_set_line(2, "1,2,3"), 2, ["poses.txt:3", "6 numbers"], id="three_numbers"),
    pytest.param(_set_line(0, "0.1,0.2,0.3,0.1,0.2,0.3,0.4"), 2, ["poses.txt:1", "got 7"], id="seven_numbers"),
    pytest.param(_set_line(1, "a,b,c,d,e,f"), 2, ["poses.txt:2", "malformed pose line"], id="letters"),
    pytest.param(_field(3, 2, "0.1.2"), 2, ["poses.txt:4"], id="two_decimal_points"),
    pytest.param(_field(3, 0, "nan"), 2, ["poses.txt:4", "nan"], id="nan"),
    pytest.param(_field(0, 1, "NaN"), 2, ["poses.txt:1", "nan"], id="NaN_upper"),
    pytest.param(_field(1, 0, "inf"), 2, ["poses.txt:2", "inf"], id="inf"),
    pytest.param(_field(1, 4, "-inf"), 2, ["poses.txt:2", "inf"], id="minus_inf"),
    pytest.param(_field(2, 0, "1e308"), 2, ["poses.txt:3", "1e+308"], id="x_1e308"),
    pytest.param(_field(2, 3, "1e308"), 2, ["poses.txt:3", "1e+308"], id="rx_1e308"),
    pytest.param(_field(2, 5, "-1e308"), 2, ["poses.txt:3"], id="rz_minus_1e308"),
    pytest.param(_field(4, 0, "1e400"), 2, ["poses.txt:5", "inf"], id="overflow_1e400"),
    pytest.param(_field(0, 0, "542.8"), 2, ["poses.txt:1", "millimetres"], id="millimetres"),
    pytest.param(_field(0, 3, "45"), 2, ["poses.txt:1", "degrees"], id="degrees"),
    pytest.param(_field(1, 2, "12345.0"), 2, ["poses.txt:2"], id="far_away"),
    pytest.param(_field(0, 0, "0x10"), 2, ["poses.txt:1"], id="hex_number"),
    pytest.param(_field(0, 0, "1,5"), 2, ["poses.txt:1"], id="decimal_comma"),
    pytest.param(lambda t: t.replace(",", ";"), 2, ["poses.txt:1", "malformed"], id="semicolons"),
    pytest.param(lambda t: t.replace(",", "\t"), 0, [], id="tabs_are_fine"),
    pytest.param(lambda t: "", 2, ["poses.txt", "no pose lines"], id="empty"),
    pytest.param(lambda t: "# only a comment\n\n", 2, ["poses.txt", "no pose lines"], id="only_comments"),
    pytest.param(lambda t: "\n".join(_lines(t)[:3]) + "\n", 2, ["poses.txt", "no pose line"], id="too_few_lines"),
    pytest.param(lambda t: t.replace("\n", "\r\n"), 0, [], id="crlf_is_fine"),
    pytest.param(lambda t: t.replace("\n", "\r"), 0, [], id="old_mac_cr_only_is_read"),
    pytest.param(_encode("utf-8", codecs.BOM_UTF8), 0, [], id="utf8_bom_is_read"),
    pytest.param(_encode("utf-16"), 0, [], id="utf16_with_bom_is_read"),
    pytest.param(_encode("utf-16-le"), 2, ["poses.txt", "UTF-16"], id="utf16_without_bom"),
    pytest.param(lambda t: ("# Genauigkeit \xb10.1 mm\n" + t).encode("latin-1"), 0, [], id="latin1_comment_is_read"),
    pytest.param(lambda t: b"\xff\xd8\xff\xe0" + bytes(range(256)) * 4, 2, ["poses.txt"], id="binary_jpeg_bytes"),
    pytest.param(lambda t: t + "0.5,0.1,0.4,0.1,0.2\x00,0.3\n", 2, ["poses.txt:7"], id="nul_byte"),
    pytest.param(lambda t: t + "[0.5, 0.1, 0.4, 0.1, 0.2, 0.3]\n", 0, [], id="list_line_is_read"),
    pytest.param(
        lambda t: t + "[[0.5, 0.1, 0.4], [0.1, 0.2]]\n", 2, ["poses.txt:7", "got 5"], id="nested_list_of_five"
    ),
    pytest.param(lambda t: t + "x=0.5 y=0.1 z=0.4\n", 2, ["poses.txt:7", "malformed"], id="key_value"),
    pytest.param(lambda t: "x,y,z,rx,ry,rz\n" + t, 0, [], id="header_line_is_skipped"),
    pytest.param(
        lambda t: "x,y,z,rx,ry,rz\nx,y,z,rx,ry,rz\n" + t, 2, ["poses.txt:2", "malformed"], id="two_header_lines"
    ),
    pytest.param(lambda t: t + "0.5,0.1,0.4,0.1,0.2,0.3\n" * 3, 0, [], id="extra_lines_are_dropped_views"),
]


@pytest.mark.parametrize("edit, code, culprits", CASES)
def test_pose_text(edit, code, culprits, tiny_vendor, copy_session, run_cli, names, fast_failed_load, tmp_path):
    s = copy_session(tiny_vendor)
    new = edit((s / "poses.txt").read_text())
    (s / "poses.txt").write_bytes(new if isinstance(new, bytes) else new.encode("utf-8"))
    rc, err = run_cli("calibrate", s, "--out", tmp_path / "out", "--no-report", "--no-refine")
    if code == 0:
        assert rc in (0, 7), err  # read: the verdict of 6 views may be FAIL, never an input error
    else:
        assert rc == code, err
        names(err, *culprits)


def test_poses_txt_is_a_folder(tiny_vendor, copy_session, run_cli, names, fast_failed_load, tmp_path):
    s = copy_session(tiny_vendor)
    (s / "poses.txt").unlink()
    (s / "poses.txt").mkdir()
    rc, err = run_cli("calibrate", s, "--out", tmp_path / "out", "--no-report")
    assert rc == 2
    names(err, "poses.txt", "not a regular file", "a folder")


@settings(max_examples=40, deadline=None, suppress_health_check=list(HealthCheck))
@given(line=st.text(alphabet=st.sampled_from(list("0123456789.,-+eE naif#\t;x")), min_size=1, max_size=40))
def test_any_garbage_line_is_one_line_naming_its_line(line, tiny_vendor, tmp_path_factory):
    """Property: a 7th pose line of any text is read (the view is dropped: no image) or refused with one
    line naming poses.txt:7; never a traceback."""
    from handeye.errors import InputError
    from handeye.session import load_session

    s = tmp_path_factory.mktemp("garbage")
    for f in tiny_vendor.iterdir():
        (s / f.name).symlink_to(f)
    (s / "poses.txt").unlink()
    (s / "poses.txt").write_text((tiny_vendor / "poses.txt").read_text() + line.replace("\n", " ") + "\n")
    try:
        session = load_session(s)
    except InputError as e:
        msg = str(e)
        assert "\n" not in msg and "poses.txt" in msg
        assert "poses.txt:7" in msg or "poses.txt:" not in msg
    else:
        assert len(session.views) == 6
