"""``python -m vnhc_gym.systems.printed [NAME ...] [--check]``: print the systems' JAX modules again
(or, with ``--check``, list those whose file differs from what printing gives, exit 1 if any)."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from functools import partial
from typing import Any

from vnhc_gym.mechanics import derive_law
from vnhc_gym.mechanics.printing import print_module
from vnhc_gym.systems.cartpole import cartpole_system
from vnhc_gym.systems.flocking import flocking_system
from vnhc_gym.systems.printed import FOLDER, SOURCES
from vnhc_gym.systems.sled import sled_system
from vnhc_gym.systems.spacecraft import spacecraft_system
from vnhc_gym.systems.usv import usv_system

#: Each printed module's sympy definition: the call named in its header, and that call.
BUILDS: dict[str, tuple[str, Callable[[], Any]]] = {
    "usv_northeast": ("usv_system('northeast')", partial(usv_system, "northeast")),
    "usv_random": ("usv_system('random')", partial(usv_system, "random")),
    "usv_affine": ("usv_system('affine')", partial(usv_system, "affine")),
    "sled": ("sled_system()", sled_system),
    "cartpole": ("cartpole_system()", cartpole_system),
    "spacecraft": ("spacecraft_system()", spacecraft_system),
    "flocking4": ("flocking_system(4)", partial(flocking_system, 4)),
    "flocking2": ("flocking_system(2)", partial(flocking_system, 2)),
}


def text(name: str) -> str:
    """What printing the system ``name`` of ``SOURCES`` gives (derives its law with sympy)."""
    call, build = BUILDS[name]
    system, constraint, *rest = build()
    outputs = rest[0] if rest else None
    return print_module(derive_law(system, constraint), f"The {name} system", f"vnhc_gym.systems.{call}", outputs)


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
