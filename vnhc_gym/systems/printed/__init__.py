"""The package's systems printed as pure ``jax.numpy`` modules (one file each, beside this one).

``SOURCES`` names each printed module and the sympy definition it is printed from;
``python -m vnhc_gym.systems.printed`` prints them all again (``--check`` only compares), and a test
holds the files to what printing gives.  Importing a printed module imports ``jax.numpy`` only.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from functools import partial
from pathlib import Path
from types import ModuleType
from typing import Any

__all__ = ["SOURCES", "load", "printed_module", "text"]

FOLDER = Path(__file__).parent


def _sources() -> dict[str, tuple[str, Callable[[], Any]]]:
    from vnhc_gym.systems.cartpole import cartpole_system
    from vnhc_gym.systems.flocking import flocking_system
    from vnhc_gym.systems.sled import sled_system
    from vnhc_gym.systems.spacecraft import spacecraft_system
    from vnhc_gym.systems.usv import usv_system

    return {
        "usv_northeast": ("usv_system('northeast')", partial(usv_system, "northeast")),
        "usv_random": ("usv_system('random')", partial(usv_system, "random")),
        "usv_affine": ("usv_system('affine')", partial(usv_system, "affine")),
        "sled": ("sled_system()", sled_system),
        "cartpole": ("cartpole_system()", cartpole_system),
        "spacecraft": ("spacecraft_system()", spacecraft_system),
        "flocking4": ("flocking_system(4)", partial(flocking_system, 4)),
        "flocking2": ("flocking_system(2)", partial(flocking_system, 2)),
    }


#: Printed module name -> the call in `vnhc_gym.systems` it is printed from.
SOURCES: tuple[str, ...] = ("usv_northeast", "usv_random", "usv_affine", "sled", "cartpole", "spacecraft", "flocking4",
                             "flocking2")


def text(name: str) -> str:
    """What printing the system ``name`` of ``SOURCES`` gives (derives its law with sympy)."""
    from vnhc_gym.mechanics import derive_law
    from vnhc_gym.mechanics.printing import print_module

    call, build = _sources()[name]
    system, constraint, *rest = build()
    outputs = rest[0] if rest else None
    return print_module(derive_law(system, constraint), f"The {name} system", f"vnhc_gym.systems.{call}", outputs)


def load(name: str) -> ModuleType:
    """The printed module of the system ``name`` (``SOURCES``)."""
    if name not in SOURCES:
        raise ValueError(f"unknown printed system {name!r}; printed: {list(SOURCES)}")
    return importlib.import_module(f"{__name__}.{name}")


def printed_module(name: str) -> str | None:
    """The import path of the printed module ``name`` (``"usv_affine"``), or None if ``SOURCES`` has
    no such module (a user's current, a flock of another size)."""
    return f"{__name__}.{name}" if name in SOURCES else None
