"""``python -m handeye.contract [--check] [DIR]``: write (or check) the published JSON schemas.

The schemas of result.json, observations.json, verify.json and batch.json, generated from the models,
go to ``DIR`` (default: the checkout's ``docs/``). ``--check`` writes nothing and exits 1 when a
published file differs from the generated one.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from . import schema_texts


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m handeye.contract", description=__doc__.splitlines()[0])
    p.add_argument("dir", nargs="?", type=Path, help="where the schemas go (default: the checkout's docs/)")
    p.add_argument("--check", action="store_true", help="compare with the published files, write nothing")
    args = p.parse_args(argv)
    if args.dir is None:
        docs = Path(__file__).resolve().parents[2] / "docs"
        if not (docs / "architecture.md").is_file():  # an installed package: no checkout around it
            p.error("give DIR: this handeye is not a checkout with docs/")
        args.dir = docs
    stale = []
    for name, text in schema_texts().items():
        path = args.dir / name
        if args.check:
            if not path.is_file() or path.read_text(encoding="utf-8") != text:
                stale.append(str(path))
        else:
            path.write_text(text, encoding="utf-8")
            print(path)
    for s in stale:
        print(f"{s}: differs from the models; run python -m handeye.contract", file=sys.stderr)
    return 1 if stale else 0


if __name__ == "__main__":
    sys.exit(main())
