"""Bad input, class "images": image paths that are not image files (folders, devices, pipes, links to
nothing), broken image bytes, one image of another size. Only regular files are ever opened."""

from __future__ import annotations

import os

import pytest


def _replace(view: str, make):
    def f(s):
        p = s / f"{view}.jpg"
        p.unlink()
        make(p)

    return f


def _bytes(data: bytes):
    return lambda p: p.write_bytes(data)


def _resized(w, h):
    def make(p):
        import cv2
        import numpy as np

        cv2.imwrite(str(p), np.full((h, w), 128, np.uint8))

    return make


# (how view "3"'s image is broken, exit code, culprits)
CASES = [
    pytest.param(_replace("3", lambda p: p.mkdir()), 2, ["view 3", "3.jpg", "a folder"], id="folder"),
    pytest.param(_replace("3", lambda p: os.mkfifo(p)), 2, ["view 3", "3.jpg", "named pipe"], id="named_pipe"),
    pytest.param(
        _replace("3", lambda p: p.symlink_to("/dev/zero")), 2, ["view 3", "3.jpg", "character device"], id="dev_zero"
    ),
    pytest.param(
        _replace("3", lambda p: p.symlink_to("/dev/null")), 2, ["view 3", "3.jpg", "character device"], id="dev_null"
    ),
    pytest.param(
        _replace("3", lambda p: p.symlink_to(p.parent / "nowhere.jpg")), 2, ["view 3", "3.jpg"], id="dangling_link"
    ),
    pytest.param(_replace("3", lambda p: p.symlink_to(p.parent)), 2, ["view 3", "a folder"], id="link_to_folder"),
    pytest.param(_replace("3", _resized(200, 150)), 2, ["view 3", "200x150", "400x300"], id="other_size"),
    pytest.param(_replace("3", _resized(300, 400)), 2, ["view 3", "300x400"], id="portrait"),
    pytest.param(_replace("1", _resized(800, 600)), 2, ["view 1", "800x600"], id="first_view_other_size"),
    pytest.param(_replace("3", _bytes(b"")), 2, ["3.jpg", "cannot be decoded"], id="empty_file"),
    pytest.param(_replace("3", _bytes(b"not an image at all")), 2, ["3.jpg", "cannot be decoded"], id="text_file"),
    pytest.param(
        _replace("3", _bytes(b"\xff\xd8\xff\xe0" + b"\x00" * 100)),
        2,
        ["3.jpg", "cannot be decoded"],
        id="truncated_jpeg",
    ),
    pytest.param(_replace("3", _bytes(os.urandom(5000))), 2, ["3.jpg", "cannot be decoded"], id="random_bytes"),
]


@pytest.mark.parametrize("breaker, code, culprits", CASES)
def test_vendor_image(breaker, code, culprits, tiny_vendor, copy_session, run_cli, names, fast_failed_load, tmp_path):
    s = copy_session(tiny_vendor)
    breaker(s)
    rc, err = run_cli("calibrate", s, "--out", tmp_path / "out", "--no-report", "--no-refine")
    assert rc == code, err
    names(err, *culprits)


NATIVE_CASES = [
    pytest.param({"image": "/dev/zero"}, 2, ["view 3", "outside the session folder"], id="abs_dev_zero"),
    pytest.param({"image": "../../../../etc/passwd"}, 2, ["view 3", "outside the session folder"], id="etc_passwd"),
    pytest.param({"image": "/etc/hostname"}, 2, ["view 3", "outside"], id="absolute_elsewhere"),
    pytest.param({"image": "."}, 2, ["view 3", "a folder"], id="session_folder_itself"),
    pytest.param({"image": ""}, 2, ["view 3"], id="empty_path"),
    pytest.param({"image": 5}, 2, ["view 3"], id="number_path"),
]


@pytest.mark.parametrize("change, code, culprits", NATIVE_CASES)
def test_native_image_path(
    change, code, culprits, tiny_native, copy_session, run_cli, names, fast_failed_load, tmp_path
):
    import yaml

    s = copy_session(tiny_native)
    doc = yaml.safe_load((s / "session.yaml").read_text())
    doc["views"][2].update(change)
    (s / "session.yaml").write_text(yaml.safe_dump(doc))
    rc, err = run_cli("calibrate", s, "--out", tmp_path / "out", "--no-report")
    assert rc == code, err
    names(err, *culprits)


def test_native_image_link_to_a_pipe(tiny_native, copy_session, run_cli, names, fast_failed_load, tmp_path):
    s = copy_session(tiny_native)
    os.mkfifo(tmp_path / "fifo")
    (s / "3.jpg").unlink()
    (s / "3.jpg").symlink_to(tmp_path / "fifo")
    rc, err = run_cli("calibrate", s, "--out", tmp_path / "out", "--no-report")
    assert rc == 2
    names(err, "view 3", "named pipe")


@pytest.mark.skipif(os.geteuid() == 0, reason="root reads every file")
def test_unreadable_image(tiny_vendor, copy_session, run_cli, names, fast_failed_load, tmp_path):
    s = copy_session(tiny_vendor)
    (s / "3.jpg").chmod(0)
    rc, err = run_cli("calibrate", s, "--out", tmp_path / "out", "--no-report")
    assert rc == 2
    names(err, "view 3", "3.jpg", "Permission denied")
