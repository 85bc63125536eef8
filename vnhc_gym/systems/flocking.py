"""Flocking by velocity alignment (paper, Section IV-A).

``N`` particles in the vertical xz-plane under gravity; the last one (the leader) falls
freely, particles ``b = 1..N-1`` are pushed by one control each, equally along x and z
(covector ``f^b = dx_b + dz_b``).  Coordinates ``q = (x_1..x_N, z_1..z_N)``:

.. math::

    m_b \\ddot x_b = u_b,\\quad m_b \\ddot z_b = u_b - m_b g,\\qquad
    \\ddot x_N = 0,\\quad \\ddot z_N = -g,

and the virtual constraint aligns each follower's velocity with the leader's,

.. math::

    \\phi^b = \\dot x_N \\dot z_b - \\dot x_b \\dot z_N \\qquad (b = 1..N-1),

satisfied by parallel and anti-parallel velocities.  ``C = diag((xd_N - zd_N)/m_b)`` is
singular where the leader moves along the diagonal ``xd_N = zd_N``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cache, partial
from typing import TYPE_CHECKING

import numpy as np

from vnhc_gym.mechanics import ConstrainedSystem
from vnhc_gym.mechanics.fleet import FleetLayout
from vnhc_gym.systems.printed import printed_module

if TYPE_CHECKING:
    from vnhc_gym.mechanics import MechanicalSystem, VelocityConstraint

__all__ = ["flocking_system", "make_flocking", "FlockingPreset", "FLOCKING_PRESETS", "MAX_AGENTS", "flocking_state"]

#: Largest number of particles of a compiled flock.
MAX_AGENTS = 1000


def _check_n_agents(n_agents: int) -> int:
    if int(n_agents) != n_agents or n_agents < 2:
        raise ValueError(f"n_agents must be an integer >= 2, got {n_agents}")
    return int(n_agents)


def flocking_system(n_agents: int = 4) -> tuple[MechanicalSystem, VelocityConstraint]:
    """Symbolic flocking system and alignment constraint for ``n_agents`` particles (leader last)."""
    import sympy as sp

    from vnhc_gym.mechanics import MechanicalSystem, VelocityConstraint

    n = _check_n_agents(n_agents)
    xs = sp.symbols(f"x_1:{n + 1}", real=True)
    zs = sp.symbols(f"z_1:{n + 1}", real=True)
    xds = sp.symbols(f"xd_1:{n + 1}", real=True)
    zds = sp.symbols(f"zd_1:{n + 1}", real=True)
    masses = sp.symbols(f"m_1:{n + 1}", positive=True)
    g = sp.Symbol("g", positive=True)
    q = (*xs, *zs)
    qd = (*xds, *zds)
    forces = sp.zeros(2 * n, n - 1)
    for b in range(n - 1):
        forces[b, b] = 1  # dx_b
        forces[n + b, b] = 1  # dz_b
    system = MechanicalSystem(
        name=f"flocking{n}", q=q, qd=qd,
        mass_matrix=sp.diag(*masses, *masses),
        control_forces=forces,
        potential=sum(mi * g * zi for mi, zi in zip(masses, zs, strict=True)),
        params={**{mi: 2.0 for mi in masses}, g: 10.0},
    )
    phi = sp.Matrix([xds[-1] * zds[b] - xds[b] * zds[-1] for b in range(n - 1)])
    return system, VelocityConstraint(phi)


@cache
def make_flocking(n_agents: int = 4) -> ConstrainedSystem:
    """Compiled flocking system of ``n_agents`` particles (cached per ``n_agents``).

    A fleet ([`ConstrainedSystem.fleet`][vnhc_gym.mechanics.ConstrainedSystem.fleet]) of
    ``n_agents - 1`` copies of the two-particle system (one follower and the leader, which every
    copy shares): the unit is derived and printed once, whatever ``n_agents`` is.  Parameters are
    ``(m_1, ..., m_N, g)``, defaults ``m_i = 2``, ``g = 10`` (the paper's); the state is
    ``(x_1..x_N, z_1..z_N, xd_1..xd_N, zd_1..zd_N)``, leader last.
    """
    n = _check_n_agents(n_agents)
    if n > MAX_AGENTS:
        raise ValueError(f"n_agents must be <= {MAX_AGENTS}, got {n}")
    unit = ConstrainedSystem.from_recipe(("flocking", 2), partial(flocking_system, 2),
                                         printed=printed_module("flocking2"))
    names = tuple(f"{c}_{i}" for c in ("x", "z", "xd", "zd") for i in range(1, n + 1))
    return ConstrainedSystem.fleet(unit, flocking_layout(n), build=partial(flocking_system, n), state_names=names)


def flocking_layout(n_agents: int) -> FleetLayout:
    """Where follower ``b`` and the leader sit in the ``n_agents``-particle state, for the fleet of
    two-particle units (unit coordinates ``(x_follower, x_leader, z_follower, z_leader)``, unit
    parameters ``(m_follower, m_leader, g)``)."""
    n = n_agents
    followers = np.arange(n - 1)
    leader = np.full(n - 1, n - 1)
    q = np.stack([followers, leader, n + followers, n + leader], axis=1)
    return FleetLayout(
        name=f"flocking{n}", n=2 * n, state_map=np.concatenate([q, 2 * n + q], axis=1),
        param_map=np.stack([followers, leader, np.full(n - 1, n)], axis=1),
        own=np.array([True, False, True, False]),
        param_names=(*(f"m_{i}" for i in range(1, n + 1)), "g"), param_defaults=(2.0,) * n + (10.0,))


def flocking_state(positions: np.ndarray, velocities: np.ndarray) -> np.ndarray:
    """Pack ``(N, 2)`` positions and velocities (x, z per particle) into ``s = (x.., z.., xd.., zd..)``."""
    pos = np.asarray(positions, dtype=np.float64)
    vel = np.asarray(velocities, dtype=np.float64)
    return np.concatenate([pos[:, 0], pos[:, 1], vel[:, 0], vel[:, 1]])


@dataclass(frozen=True)
class FlockingPreset:
    """A named parameter set and initial state (see ``FLOCKING_PRESETS``)."""

    name: str
    positions: tuple[tuple[float, float], ...]
    velocities: tuple[tuple[float, float], ...]
    masses: tuple[float, ...]
    g: float
    dt: float
    duration: float
    gain: float = 1.0
    description: str = ""
    extra: dict[str, float] = field(default_factory=dict)

    @property
    def n_agents(self) -> int:
        return len(self.positions)

    def state(self) -> np.ndarray:
        return flocking_state(np.array(self.positions), np.array(self.velocities))

    def params(self) -> np.ndarray:
        return np.array([*self.masses, self.g], dtype=np.float64)


#: Public preset names (keep them stable).
FLOCKING_PRESETS: dict[str, FlockingPreset] = {
    "paper": FlockingPreset(
        name="paper",
        positions=((10.0, 56.0), (30.0, 100.0), (50.0, 100.0), (10.0, 90.0)),
        velocities=((0.5, 1.0), (1.0, 1.0), (-1.0, -1.0), (0.6, 0.0)),
        masses=(2.0, 2.0, 2.0, 2.0), g=10.0, dt=0.01, duration=500.0, gain=1.0,
        description="Section IV-A: m_i = 2, g = 10, dt = 0.01, 500 s, K = I.",
    ),
}
