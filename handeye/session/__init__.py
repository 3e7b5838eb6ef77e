"""Reading sessions from disk: the only code that reads inputs.

- :mod:`.vendor`: the vendor folder as it is (config.yaml, poses.txt, numbered images);
- :mod:`.native`: handeye's session.yaml (any pose format, optional intrinsics, view records);
- :mod:`.target_spec`: the ``target:`` section -> a target spec;
- :mod:`.fields`: validated fields, unit plausibility, where a session's files are;
- :mod:`.raw`: the lenient reading for the diagnostics (raw pose numbers, no unit checks);
- :mod:`.importers`: other tools' layouts (ViSP, industrial_calibration) -> session.yaml.

Strict loading validates everything once; errors name the file (and line) and what to do. Poses are
converted to ``T_base_end`` (metres) at this boundary. See docs/session_format.md.
"""

from __future__ import annotations

from pathlib import Path

from ..records import Session
from .fields import locate_session
from .native import load_native_session
from .vendor import load_vendor_session


def load_session(
    path: str | Path, *, mode: str | None = None, allow_outside: bool = False, check_sizes: bool = True
) -> Session:
    """Load a session folder (native ``session.yaml`` or vendor ``poses.txt``), or a session.yaml path.

    ``mode`` overrides the mode stated in the session (the CLI's ``--mode``). ``allow_outside`` lets a
    native session's image and pose-file paths leave the session folder (and its ``image_folder``);
    by default such a path is an InputError. A vendor session's images are always its folder's.
    ``check_sizes``: read the images' headers for :func:`check_image_sizes`; a calibration passes False, its
    detection checks the sizes of the images it decodes (each image read once).
    """
    kind, p = locate_session(path)
    if kind == "native":
        session = load_native_session(p, mode=mode, allow_outside=allow_outside)
    else:
        session = load_vendor_session(p, mode=mode)
    if check_sizes:
        check_image_sizes(session)
    return session


def image_sizes(items) -> dict:
    """View id -> (width, height) of its image for (view id, image path) ``items``.

    View id -> (width, height) of its image for (view id, image path) ``items`` (or a Session's views), read
    from the file header (nothing is decoded); views without an image (pose-only views), or whose header cannot
    be read (left to detection, which drops them with the reason), are left out.
    """
    from PIL import Image, UnidentifiedImageError

    if isinstance(items, Session):
        items = [(v.view_id, v.image_path) for v in items.views]
    sizes = {}
    for vid, path in items:
        if path is None:
            continue
        try:
            with Image.open(path) as im:
                sizes[vid] = tuple(im.size)
        except (OSError, UnidentifiedImageError, ValueError, Image.DecompressionBombError):
            continue
    return sizes


def check_image_sizes(session: Session) -> None:
    """All views' images of one size.

    All views' images of one size (:func:`image_sizes`, from the files' headers): an image of another size than
    the others is an InputError naming its view (:func:`handeye.detect.size_mismatch_error`).
    """
    from ..detect import size_mismatch_error

    err = size_mismatch_error(image_sizes(session), lambda vid: session.view(vid).image_path)
    if err is not None:
        raise err
