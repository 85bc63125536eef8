"""A fleet's printed system as pure ``jax.numpy`` functions: ``jax.vmap`` over one printed unit.

A fleet (`vnhc_gym.mechanics.fleet`) is ``R`` copies of one unit system that share an autonomous
part: each follower of a flock with its leader is the same two-particle system.  Printing the
fleet written out would give code (and a sympy derivation, and a compile time) that grows with
``R``; here the unit is printed once (`vnhc_gym.systems.printed`) and `FleetSystem` runs it on every
copy at once with ``jax.vmap``, gathering copy ``b``'s unit state and parameters through the same
`FleetLayout`.  The result has the attributes and functions of a printed
module (``N``, ``M``, ``HOLONOMIC``, ``drift``, ``input_fields``, ``phi``, ``decoupling_matrix``,
``drift_term``, ...), so that `vnhc_gym.mechanics.functional` and
`vnhc_gym.envs.functional` run on it unchanged.

Why it is exact: ``phi^b`` involves only copy ``b``'s coordinates and the shared ones, and copy
``b``'s controls move only its own coordinates, so ``phi`` and ``G`` stack the copies' values and
``C`` is block-diagonal with the copies' blocks; the shared coordinates' accelerations depend on
neither the copies' coordinates nor the controls (`vnhc_gym.mechanics.fleet.check_autonomous`, run
when a fleet of a derived unit is made, and by a test on the flock's printed unit), so any copy's drift
gives them (copy 0's is taken).

Every function takes one state ``s`` (shape ``(2 N,)``) and one parameter vector ``p`` and is pure:
``jax.jit``, ``jax.vmap`` (over episodes) and differentiation apply as to a printed module.  The
precision is the caller's.
"""

from __future__ import annotations

from collections.abc import Sequence
from types import ModuleType
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from vnhc_gym.mechanics.fleet import FleetLayout

__all__ = ["FleetSystem"]

Array = Any  # a jax.Array


class FleetSystem:
    """A fleet of copies of a printed unit system, with a printed module's interface.

    Parameters
    ----------
    unit : module
        The unit's printed module (`vnhc_gym.systems.printed`), e.g. ``flocking2`` for one
        follower and the leader.
    layout : FleetLayout
        Where each copy sits in the fleet's state and parameters (e.g.
        `vnhc_gym.systems.flocking.flocking_layout`).  Its checks (every fleet coordinate owned by
        exactly one copy or shared, velocities at ``index + n``) are what make the maps below
        permutations.
    state_names : sequence of str, optional
        The fleet's state names (``q`` then ``qd``); default ``s_0, s_1, ...`` (a layout does not
        name its coordinates).

    Attributes
    ----------
    N, M : int
        Coordinates and controls of the fleet: ``layout.n`` and ``R`` times the unit's ``M``.
    HOLONOMIC : bool
        The unit's.
    NAME : str
        The layout's name.
    STATE_NAMES, PARAM_NAMES, PARAM_DEFAULTS, PARAM_POSITIVE, OUTPUT_NAMES : tuple
        As in a printed module; the parameters are the layout's (positive where some copy reads a
        positive unit parameter).
    R : int
        Number of copies.
    UNIT : module
        The unit's printed module.

    Notes
    -----
    Copy ``b``'s controls, ``phi``, ``G`` (and ``phi_h``, the extra outputs) are entries
    ``b UM .. (b + 1) UM - 1`` of the fleet's.  ``phi_h``
    exists only for a holonomic unit and ``outputs`` only for a unit with extra outputs, as in a
    printed module.
    """

    def __init__(self, unit: ModuleType, layout: FleetLayout, state_names: Sequence[str] | None = None) -> None:
        un, um = int(unit.N), int(unit.M)
        n_unit_params = len(unit.PARAM_NAMES)
        if layout.own.shape[0] != un or layout.state_map.shape[1] != 2 * un or \
                layout.param_map.shape[1] != n_unit_params:
            raise ValueError(f"the layout {layout.name!r} does not fit the unit (N = {un}, {n_unit_params} "
                             f"parameters): state_map has {layout.state_map.shape[1]} columns, own "
                             f"{layout.own.shape[0]} entries, param_map {layout.param_map.shape[1]} columns")
        r = layout.replicas
        n = int(layout.n)
        n_out = len(getattr(unit, "OUTPUT_NAMES", ()))
        if n_out and len(layout.output_names) != r * n_out:
            raise ValueError(f"the layout {layout.name!r} names {len(layout.output_names)} outputs, but {r} copies "
                             f"of the unit have {r * n_out}")
        names = tuple(state_names) if state_names is not None else tuple(f"s_{i}" for i in range(2 * n))
        if len(names) != 2 * n:
            raise ValueError(f"state_names must have {2 * n} entries, got {len(names)}")

        self.UNIT = unit
        self.NAME = layout.name
        self.R = r
        self.N = n
        self.M = r * um
        self.HOLONOMIC = bool(unit.HOLONOMIC)
        self.STATE_NAMES = names
        self.PARAM_NAMES = tuple(layout.param_names)
        self.PARAM_DEFAULTS = tuple(float(v) for v in layout.param_defaults)
        # A fleet parameter is positive where some copy reads it as a positive unit parameter.
        positive = np.zeros(len(layout.param_names), dtype=bool)
        for row in np.asarray(layout.param_map):
            positive[row[np.asarray(unit.PARAM_POSITIVE, dtype=bool)]] = True
        self.PARAM_POSITIVE = tuple(bool(v) for v in positive)
        self.OUTPUT_NAMES = tuple(layout.output_names) if n_out else ()
        self._un, self._um = un, um
        # Gather maps (numpy constants: under jit they become constant index arrays, whatever R is).
        # int32: JAX's indexing fails on int64 index arrays when float64 (and int64) is off.
        self._state_map = np.asarray(layout.state_map, dtype=np.int32)  # (R, 2 UN)
        self._param_map = np.asarray(layout.param_map, dtype=np.int32)  # (R, UNP)
        own = np.asarray(layout.own, dtype=bool)
        self._own = own
        q_map = self._state_map[:, :un]  # the fleet coordinate of each unit coordinate, per copy
        # The fleet's accelerations as a gather from [every copy's own entries, copy 0's shared ones]:
        # the layout makes these fleet indices a permutation of range(N), so its inverse puts them in order.
        order = np.concatenate([q_map[:, own].reshape(-1), q_map[0, ~own]])
        self._accel_from = np.argsort(order).astype(np.int32)
        # Y[q_map[b, i], b UM + a] = copy b's Y[i, a] for its own coordinates i (the shared ones have
        # no input: check_autonomous).
        rows = q_map[:, own]  # (R, n_own)
        cols = np.arange(r * um, dtype=np.int32).reshape(r, um)  # (R, UM): copy b's controls
        self._y_rows = np.broadcast_to(rows[:, :, None], (r, rows.shape[1], um))
        self._y_cols = np.broadcast_to(cols[:, None, :], (r, rows.shape[1], um))
        # C's blocks on the diagonal: (R, UM, R, UM) mask of the entries of copy b's block.
        self._block_mask = np.eye(r, dtype=bool)[:, None, :, None]
        if self.HOLONOMIC:
            self.phi_h = self._phi_h
        if n_out:
            self.outputs = self._outputs

    def __repr__(self) -> str:
        return f"FleetSystem({self.R} copies of {self.UNIT.__name__}, N={self.N}, M={self.M})"

    # ------------------------------------------------------------------ the copies
    def _units(self, s: Array, p: Array) -> tuple[Array, Array]:
        """Every copy's unit state ``(R, 2 UN)`` and unit parameters ``(R, UNP)``."""
        return jnp.asarray(s)[self._state_map], jnp.asarray(p)[self._param_map]

    def _each(self, name: str, s: Array, p: Array) -> Array:
        """The unit's function ``name`` on every copy, stacked on a leading axis of length ``R``."""
        return jax.vmap(getattr(self.UNIT, name))(*self._units(s, p))

    # ------------------------------------------------------------------ a printed module's functions
    def drift(self, s: Array, p: Array) -> Array:
        """Drift acceleration ``a0`` (no control), shape ``(N,)``: each copy's own coordinates from
        that copy, the shared ones from copy 0."""
        a0 = self._each("drift", s, p)  # (R, UN)
        values = jnp.concatenate([a0[:, self._own].reshape(-1), a0[0, ~self._own]])
        return values[self._accel_from]

    def input_fields(self, s: Array, p: Array) -> Array:
        """Input fields ``Y``, shape ``(N, M)``: copy ``b``'s controls move only its own coordinates."""
        y = self._each("input_fields", s, p)  # (R, UN, UM)
        y_own = y[:, self._own, :]
        return jnp.zeros((self.N, self.M), y.dtype).at[self._y_rows, self._y_cols].set(y_own, unique_indices=True)

    def phi(self, s: Array, p: Array) -> Array:
        """The constraint ``phi`` (``psi`` for a holonomic one), shape ``(M,)``: the copies' in order."""
        return self._each("phi", s, p).reshape(-1)

    def _phi_h(self, s: Array, p: Array) -> Array:
        """Holonomic constraint values, shape ``(M,)``."""
        return self._each("phi_h", s, p).reshape(-1)

    def decoupling_matrix(self, s: Array, p: Array) -> Array:
        """Decoupling matrix ``C``, shape ``(M, M)``: block-diagonal with the copies' ``UM x UM`` blocks
        (exact zeros off the blocks, even where a block is not finite)."""
        c = self._each("decoupling_matrix", s, p)  # (R, UM, UM)
        full = jnp.where(self._block_mask, c[:, :, None, :], jnp.zeros((), c.dtype))  # (R, UM, R, UM)
        return full.reshape(self.M, self.M)

    def drift_term(self, s: Array, p: Array) -> Array:
        """``G``: the rate of ``phi`` along the drift, shape ``(M,)``: the copies' in order."""
        return self._each("drift_term", s, p).reshape(-1)

    def singular_sizes(self, s: Array, p: Array) -> Array:
        """The squared sizes of ``C``'s factors, shape ``(2 M,)``: every copy's ``|J_b|^2``, then every
        copy's ``|Y^a|^2``."""
        sizes = self._each("singular_sizes", s, p)  # (R, 2 UM)
        return jnp.concatenate([sizes[:, :self._um].reshape(-1), sizes[:, self._um:].reshape(-1)])

    def transversality(self, s: Array, p: Array) -> Array:
        """The law's singular test: the smallest of the copies' measures (``C`` is block-diagonal, so its
        smallest singular value, normalised, is the smallest of its blocks')."""
        from vnhc_gym.mechanics.functional import measure

        c = self._each("decoupling_matrix", s, p)
        sizes = self._each("singular_sizes", s, p)
        return jnp.min(jax.vmap(measure)(c, sizes))

    def energy(self, s: Array, p: Array) -> Array:
        """Mechanical energy, a scalar: the copies' unit energies with the shared part counted once
        (minus ``R - 1`` times copy 0's energy with its own coordinates at zero; exact when the unit's
        potential vanishes with them, as gravity's does at zero height)."""
        us, up = self._units(s, p)
        total = jnp.sum(jax.vmap(self.UNIT.energy)(us, up))
        own2 = np.concatenate([self._own, self._own])
        shared_only = jnp.where(own2, jnp.zeros((), us.dtype), us[0])
        return total - (self.R - 1) * self.UNIT.energy(shared_only, up[0])

    def _outputs(self, s: Array, p: Array) -> Array:
        """The copies' extra outputs, copy ``b``'s after copy ``b - 1``'s."""
        return self._each("outputs", s, p).reshape(-1)
