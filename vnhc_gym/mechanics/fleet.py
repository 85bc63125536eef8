"""Fleets: many copies of one unit system that share an autonomous part, derived once for any size.

Flocking is the example: each follower with the leader is the same two-particle system, and the
leader falls freely whatever the followers do.  Written out for ``N`` particles, the derivation
(and the printed code, and its compile time) would grow with ``N``; as a fleet, the unit system is
derived and printed once and ``jax.vmap`` over the copies does the rest
(`vnhc_gym.mechanics.functional_fleet`).

The fleet's law is the unit's law copy by copy: ``phi^b`` involves only copy ``b``'s coordinates,
copy ``b``'s controls move only its own coordinates, so ``C`` is block-diagonal with the units'
blocks and ``G`` stacks the units' ``G``.  This needs the shared coordinates to evolve on their own
(their accelerations depend on neither the copies' coordinates nor the controls), which
`check_autonomous` verifies on the unit's symbolic law.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from vnhc_gym.mechanics._checks import check_param

if TYPE_CHECKING:
    from vnhc_gym.mechanics.constraint import SymbolicLaw

__all__ = ["FleetLayout", "check_autonomous"]


@dataclass(frozen=True, eq=False)
class FleetLayout:
    """Where each copy of a unit system sits in the fleet's state and parameters.

    Parameters
    ----------
    name : str
        The fleet's name (reprs, messages).
    n : int
        The fleet's number of coordinates.
    state_map : array of int, shape (R, 2 n_unit)
        The fleet-state index of each entry of copy ``b``'s unit state ``(q, qd)``.
    param_map : array of int, shape (R, n_unit_params)
        The fleet-parameter index of each unit parameter of copy ``b``.
    own : array of bool, shape (n_unit,)
        The unit coordinates each copy owns; the others are shared by every copy (same fleet index
        for all) and must evolve on their own.
    param_names : tuple of str
        The fleet's parameter names, in the order of its parameter vector.
    param_defaults : tuple of float
    output_names : tuple of str
        Names of the copies' extra outputs (copy ``b``'s after copy ``b - 1``'s).
    """

    name: str
    n: int
    state_map: NDArray[np.int64]
    param_map: NDArray[np.int64]
    own: NDArray[np.bool_]
    param_names: tuple[str, ...]
    param_defaults: tuple[float, ...]
    output_names: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        sm = np.asarray(self.state_map, dtype=np.int64)
        pm = np.asarray(self.param_map, dtype=np.int64)
        own = np.asarray(self.own, dtype=np.bool_)
        object.__setattr__(self, "state_map", sm)
        object.__setattr__(self, "param_map", pm)
        object.__setattr__(self, "own", own)
        nu = own.shape[0]
        if sm.ndim != 2 or sm.shape[1] != 2 * nu or sm.shape[0] < 1:
            raise ValueError(f"state_map must have shape (R, {2 * nu}), got {sm.shape}")
        if pm.ndim != 2 or pm.shape[0] != sm.shape[0]:
            raise ValueError(f"param_map must have shape ({sm.shape[0]}, n_unit_params), got {pm.shape}")
        if len(self.param_defaults) != len(self.param_names):
            raise ValueError("param_defaults and param_names must have the same length")
        for name, value in zip(self.param_names, self.param_defaults, strict=True):
            check_param(name, value, False, f"FleetLayout {self.name!r} param_defaults")  # signs: the unit's
        n_params = len(self.param_names)
        if sm.min() < 0 or sm.max() >= 2 * self.n or pm.min(initial=0) < 0 or pm.max(initial=0) >= n_params:
            raise ValueError("state_map / param_map index outside the fleet's state / parameters")
        own2 = np.concatenate([own, own])
        shared = sm[:, ~own2]
        if (shared != shared[:1]).any():
            raise ValueError("shared unit coordinates must map to the same fleet index in every copy")
        owned = sm[:, own2].ravel()
        covered = np.concatenate([owned, shared[0]])
        if np.unique(owned).size != owned.size or np.unique(covered).size != 2 * self.n:
            raise ValueError("every fleet state entry must belong to exactly one copy or to the shared part")
        if not np.array_equal(sm[:, nu:], sm[:, :nu] + self.n):
            raise ValueError("state_map must put each unit velocity at its coordinate's index + n (the state is "
                             "(q, qd))")

    @property
    def replicas(self) -> int:
        """Number of copies ``R``."""
        return int(self.state_map.shape[0])


def check_autonomous(law: SymbolicLaw, own: NDArray[np.bool_]) -> None:
    """Raise ``ValueError`` unless the unit's shared coordinates evolve on their own: their drift
    does not involve the unit's own coordinates and no control moves them."""
    import sympy as sp

    system = law.system
    mine = {system.q[i] for i in range(system.n) if own[i]} | {system.qd[i] for i in range(system.n) if own[i]}
    for i in range(system.n):
        if own[i]:
            continue
        if law.a0[i].free_symbols & mine:
            raise ValueError(f"shared coordinate {system.q[i]} is driven by the copies' own coordinates "
                             f"({sorted(map(str, law.a0[i].free_symbols & mine))}): not a fleet")
        if any(sp.simplify(law.Y[i, a]) != 0 for a in range(system.m)):
            raise ValueError(f"shared coordinate {system.q[i]} is moved by a control: not a fleet")
