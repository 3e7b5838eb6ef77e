"""The checkout imports like the installed package, and the wheel holds every file once.

``configs/`` and ``factors/`` are installed as ``handeye.configs`` and ``handeye.factors``
(pyproject's package-dir); the links ``handeye/configs`` and ``handeye/factors`` give the checkout
the same layout, so ``python -m handeye.cli`` run with the checkout as cwd or on PYTHONPATH (as
tests do) finds them whether handeye is installed editable, non-editable or not at all.
"""

from __future__ import annotations

import importlib.metadata
import subprocess
import sys
import zipfile
from collections import Counter
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _installed() -> bool:
    try:
        importlib.metadata.version("handeye")
    except importlib.metadata.PackageNotFoundError:
        return False
    return True


def test_the_checkout_has_the_installed_layout():
    for name in ("configs", "factors"):
        link = ROOT / "handeye" / name
        assert link.resolve() == (ROOT / name).resolve(), f"handeye/{name} must lead to {name}/"
    code = "import handeye, handeye.cli, handeye.configs, handeye.factors; print(handeye.configs.__file__)"
    env = {"PATH": "/usr/bin:/bin", "PYTHONNOUSERSITE": "1"}
    if _installed():  # -I: no cwd on sys.path, no PYTHONPATH: the interpreter's own install also has them
        out = subprocess.run([sys.executable, "-I", "-c", code], cwd=ROOT, capture_output=True, text=True, env=env)
        assert out.returncode == 0, out.stderr
    out = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, env={**env, "PYTHONPATH": str(ROOT)}
    )
    assert out.returncode == 0, out.stderr
    assert Path(out.stdout.strip()).resolve() == (ROOT / "configs" / "__init__.py").resolve()


def test_the_wheel_holds_configs_and_factors_once_and_no_links(tmp_path):
    try:  # the build requirements of pyproject.toml, here (no download: --no-build-isolation)
        import setuptools
        import wheel  # noqa: F401
    except ImportError as e:
        pytest.skip(f"building the wheel needs setuptools >= 68 and wheel ({e})")
    if int(setuptools.__version__.split(".")[0]) < 68:
        pytest.skip(f"building the wheel needs setuptools >= 68 (this one is {setuptools.__version__})")
    cmd = [sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--no-build-isolation", "-w", str(tmp_path)]
    out = subprocess.run([*cmd, str(ROOT)], capture_output=True, text=True, cwd=tmp_path)
    assert out.returncode == 0, out.stderr[-3000:]
    (whl,) = tmp_path.glob("handeye-*.whl")
    with zipfile.ZipFile(whl) as z:
        infos = z.infolist()
    names = [i.filename for i in infos]
    assert [n for n, k in Counter(names).items() if k > 1] == []
    assert [i.filename for i in infos if (i.external_attr >> 16) & 0o170000 == 0o120000] == []  # no link entries
    for name, pattern in (("configs", "*.yaml"), ("factors", "*.py")):
        shipped = sorted(f"handeye/{name}/{p.name}" for p in (ROOT / name).glob(pattern))
        assert shipped and set(shipped) <= set(names)
        assert not [n for n in names if f"{name}/" in n and not n.startswith(f"handeye/{name}/")]
    assert "handeye/configs/robots/rm65.yaml" in names
    # every module of the checkout is in the wheel (a subpackage missing from pyproject's list is not)
    modules = sorted(p.relative_to(ROOT).as_posix() for p in (ROOT / "handeye").rglob("*.py"))
    assert [m for m in modules if m not in names] == []


def test_every_subpackage_is_in_the_package_list():
    """pyproject.toml lists the packages a wheel holds; a subpackage left out installs without it."""
    import tomllib

    listed = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    on_disk = {
        ".".join(p.parent.relative_to(ROOT).parts)
        for p in (ROOT / "handeye").rglob("__init__.py")
        if p.parent.parent.name != "handeye" or p.parent.name not in ("configs", "factors")
    } | {"handeye.configs", "handeye.factors"}
    assert on_disk - listed == set() and listed - on_disk == set()
