"""Checks of numeric parameters and states shared by the symbolic and the compiled side.

Plain numpy (no sympy, no JAX): [`MechanicalSystem`][vnhc_gym.mechanics.system.MechanicalSystem] checks its
default values with `check_param`, [`ConstrainedSystem`][vnhc_gym.mechanics.ConstrainedSystem] checks
whole batches with `check_param_rows` and `check_state_rows`, one vectorised
comparison per call and a search for the culprit only when one exists.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

__all__ = ["check_param", "check_param_rows", "check_state_rows", "lower_bounds"]


def check_param(name: str, value: object, positive: bool, where: str) -> float:
    """``value`` as a float, or a ``ValueError`` that names ``where`` and the parameter.

    Parameters
    ----------
    name : str
        The parameter's name.
    value : object
        Its value; must convert to a finite float, and be > 0 if ``positive``.
    positive : bool
        Whether the parameter is declared positive (a sympy symbol with ``positive=True``).
    where : str
        What is being checked, for the message (e.g. ``"MechanicalSystem(params=...)"``).
    """
    try:
        v = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise ValueError(f"{where}: parameter {name!r} must be a real number, got {value!r}") from None
    if not math.isfinite(v):
        raise ValueError(f"{where}: parameter {name!r} = {v}: expected a finite number")
    if positive and not v > 0.0:
        raise ValueError(f"{where}: parameter {name!r} = {v}: expected a number > 0 (it is declared positive)")
    return v


def lower_bounds(positive: Sequence[bool]) -> NDArray[np.float64]:
    """Per parameter, the value it must exceed: 0 if declared positive, else ``-inf``."""
    return np.where(np.asarray(positive, dtype=bool), 0.0, -np.inf).astype(np.float64)


def check_param_rows(p: NDArray[np.float64], names: Sequence[str], lower: NDArray[np.float64], batched: bool,
                     what: str = "params") -> None:
    """Raise ``ValueError`` unless every entry of ``p`` (shape ``(B, n_params)``) is finite and above
    its lower bound (``lower``, from `lower_bounds`).

    The message names the first offending row (if ``batched``: the caller passed a batch; else
    every row is the one vector it passed), the parameter, its value and what was expected.
    """
    # One comparison per entry: NaN fails both, inf the second, a non-positive value of a
    # positive parameter the first.
    if bool(np.all(p > lower)) and bool(np.all(p < np.inf)):
        return
    bad = ~((p > lower) & (p < np.inf))
    r, j = (int(i) for i in np.argwhere(bad)[0])
    v = float(p[r, j])
    where = f"{what} row {r}" if batched else what
    n_rows = int(bad.any(axis=1).sum())
    more = f" ({n_rows - 1} more row{'s' if n_rows > 2 else ''} also invalid)" if batched and n_rows > 1 else ""
    if not math.isfinite(v):
        raise ValueError(f"{where}: parameter {names[j]!r} = {v}: expected a finite number{more}")
    raise ValueError(f"{where}: parameter {names[j]!r} = {v}: expected a number > 0 (it is declared positive)"
                     f"{more}")


def check_state_rows(s: NDArray[np.float64], n: int, batched: bool, why: str) -> None:
    """Raise ``ValueError`` unless every entry of the states ``s`` (shape ``(B, 2n)``, ``(q, qd)``) is
    finite; the message names the first offending row (if ``batched``), the entry and ``why``."""
    if bool(np.all(np.isfinite(s))):
        return
    bad = ~np.isfinite(s)
    r, j = (int(i) for i in np.argwhere(bad)[0])
    label = f"q[{j}]" if j < n else f"qd[{j - n}]"
    where = f"state row {r}" if batched else "state"
    n_rows = int(bad.any(axis=1).sum())
    more = f" ({n_rows - 1} more row{'s' if n_rows > 2 else ''} also non-finite)" if batched and n_rows > 1 else ""
    raise ValueError(f"{where}: entry {j} ({label}) = {float(s[r, j])}: expected a finite number; {why}{more}")
