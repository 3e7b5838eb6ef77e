"""Property tests of the result reader: a real result.json mutated (keys dropped, types changed, NaN, huge
numbers, text in number slots, nested garbage) is read into a valid model or refused with one InputError,
never another exception; what it accepts, the recalibration, export and the commands use without exit 1."""

import copy
import json
import tempfile
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from handeye.cli import main
from handeye.contract import Result, validate_result
from handeye.errors import InputError

SCALARS = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(min_value=-(10**6), max_value=10**6),
    st.sampled_from([10**400, -(10**400), 0, -1, 1e308, 1e-320]),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=6),
    st.sampled_from(["abc", "nan", "1e999", "", "ok", "failed", "eye_to_hand", "PASS", "T_base_cam", "fx"]),
)
GARBAGE = st.recursive(
    SCALARS,
    lambda inner: st.one_of(st.lists(inner, max_size=4), st.dictionaries(st.text(max_size=5), inner, max_size=4)),
    max_leaves=10,
)


def _paths(d, prefix=(), out=None) -> list:
    """Every key path of ``d`` (lists: their first three items), the top level first."""
    out = [] if out is None else out
    items = d.items() if isinstance(d, dict) else enumerate(d[:3]) if isinstance(d, list) else ()
    for k, v in items:
        out.append(prefix + (k,))
        _paths(v, prefix + (k,), out)
    return out


def _mutate(d: dict, data) -> None:
    paths = _paths(d)
    if not paths:
        return
    path = data.draw(st.sampled_from(paths), label="path")
    parent = d
    for k in path[:-1]:
        parent = parent[k]
    how = data.draw(st.sampled_from(["drop", "garbage", "number", "wrap"]), label="how")
    if how == "drop":
        del parent[path[-1]]
    elif how == "garbage":
        parent[path[-1]] = data.draw(GARBAGE, label="value")
    elif how == "number":
        parent[path[-1]] = data.draw(st.sampled_from([float("nan"), float("inf"), 10**400, "1.5", True]))
    else:  # the value one level deeper
        parent[path[-1]] = [parent[path[-1]]]


@pytest.fixture(scope="module")
def originals(results) -> dict:
    return {n: json.loads((results[n] / "result.json").read_text()) for n in ("images", "pose_only", "failed")}


def _mutated(originals, data) -> dict:
    d = copy.deepcopy(originals[data.draw(st.sampled_from(sorted(originals)), label="result")])
    for _ in range(data.draw(st.integers(1, 3), label="n_mutations")):
        _mutate(d, data)
    return d


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_a_mutated_result_is_read_or_refused_in_one_line(originals, data):
    from handeye.export import export_transform
    from handeye.recal.compare import compare_loaded
    from handeye.recal.loaded import load_result

    d = _mutated(originals, data)
    try:
        m = validate_result(d, source="result.json")
    except InputError as e:
        assert len(str(e).splitlines()) == 1 and str(e).startswith("result.json: ")
        return
    assert isinstance(m, Result) and m.raw is d
    try:  # what the reader accepted, the readers behind it use without another exception
        r = load_result(d)
        compare_loaded(r, r)
        export_transform(d, force=True)
    except InputError as e:
        assert len(str(e).splitlines()) == 1


GENERATED = st.fixed_dictionaries(
    {"handeye_result": st.just(1), "status": st.sampled_from(["ok", "failed"])},
    optional={k: GARBAGE for k in Result.model_fields if k not in ("handeye_result", "status")},
)


@settings(max_examples=200, deadline=None)
@given(d=GENERATED)
def test_a_generated_result_is_read_or_refused_in_one_line(d):
    from handeye.recal.loaded import load_result

    try:
        m = validate_result(d, source="result.json")
    except InputError as e:
        assert len(str(e).splitlines()) == 1 and str(e).startswith("result.json: ")
        return
    assert isinstance(m, Result) and (not m.ok or m.T_x is not None)
    load_result(d)


@settings(
    max_examples=6,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],  # capsys: read before each
)
@given(data=st.data())
def test_commands_never_exit_1_on_a_mutated_result(originals, results, data, capsys):
    d = _mutated(originals, data)
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "r"
        folder.mkdir()
        (folder / "result.json").write_text(json.dumps(d))
        end_pose = ["--end-pose", "0.5", "0", "0.5", "3.1", "0", "0"]
        for argv in (
            [
                "verify",
                results["images"].parent / "images_s",
                "--against",
                folder,
                "--no-report",
                "--out",
                Path(tmp) / "v",
            ],
            ["compare", results["images"], folder],
            ["export", folder, "--to", "yaml", "--out", Path(tmp) / "x.yaml"],
            ["apply", folder, "--point", "0", "0", "0.5", *end_pose],
            ["report", folder, "--format", "md", "--out", Path(tmp) / "rep"],
        ):
            capsys.readouterr()
            rc = main(["-q", *map(str, argv)])
            cap = capsys.readouterr()
            assert rc != 1 and "Traceback" not in cap.err, (argv[0], rc, cap.err)
