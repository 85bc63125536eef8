"""The package's systems printed as pure ``jax.numpy`` modules (one file each, beside this one).

``SOURCES`` names each printed module.  ``python -m vnhc_gym.systems.printed`` (`__main__`, where
each module's sympy definition is named) prints them all again, ``--check`` only compares, and a
test holds the files to what printing gives.  Importing a printed module imports ``jax.numpy`` only.
"""

from __future__ import annotations

import importlib
from pathlib import Path
from types import ModuleType

__all__ = ["SOURCES", "load", "printed_module"]

FOLDER = Path(__file__).parent

#: The printed modules, by name (their sympy definitions: `__main__.BUILDS`).
SOURCES: tuple[str, ...] = ("usv_northeast", "usv_random", "usv_affine", "sled", "cartpole", "spacecraft", "flocking4",
                             "flocking2")


def load(name: str) -> ModuleType:
    """The printed module of the system ``name`` (``SOURCES``)."""
    if name not in SOURCES:
        raise ValueError(f"unknown printed system {name!r}; printed: {list(SOURCES)}")
    return importlib.import_module(f"{__name__}.{name}")


def printed_module(name: str) -> str | None:
    """The import path of the printed module ``name`` (``"usv_affine"``), or None if ``SOURCES`` has
    no such module (a user's current, a flock of another size)."""
    return f"{__name__}.{name}" if name in SOURCES else None
