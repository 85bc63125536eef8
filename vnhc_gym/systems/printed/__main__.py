"""``python -m vnhc_gym.systems.printed [NAME ...] [--check]``: print the systems' JAX modules again
(or, with ``--check``, list those whose file differs from what printing gives, exit 1 if any)."""

from __future__ import annotations

import argparse
import sys

from vnhc_gym.systems.printed import FOLDER, SOURCES, text


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m vnhc_gym.systems.printed", description=__doc__)
    ap.add_argument("names", nargs="*", default=list(SOURCES), help=f"from {list(SOURCES)} (default: all)")
    ap.add_argument("--check", action="store_true", help="compare only; exit 1 if a file is out of date")
    args = ap.parse_args(argv)
    stale = []
    for name in args.names:
        path = FOLDER / f"{name}.py"
        new = text(name)
        if args.check:
            if not path.exists() or path.read_text() != new:
                stale.append(name)
        else:
            path.write_text(new)
            print(f"wrote {path}")
    if stale:
        print(f"out of date: {stale}; run python -m vnhc_gym.systems.printed {' '.join(stale)}")
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
