"""Fleets (``vnhc_gym.mechanics.fleet``): flocking as copies of one two-particle unit.

The fleet must be the written-out system (``flocking_system(n)``, derived and lambdified as one
system) up to rounding, for every function; it must build and run for any size up to
``MAX_AGENTS``; its layout and its unit are checked.  The last part checks the singular test of
the law: relative to ``C``'s own scale, so that scaling ``C`` never changes the verdict.
"""

from __future__ import annotations

from functools import cache

import jax
import numpy as np
import pytest
import sympy as sp

from vnhc_gym.mechanics import (
    FLAG_NONFINITE,
    FLAG_SINGULAR,
    ConstrainedSystem,
    MechanicalSystem,
    SingularControlError,
    VelocityConstraint,
    derive_law,
    simulate,
)
from vnhc_gym.mechanics import functional as F
from vnhc_gym.mechanics.fleet import FleetLayout, check_autonomous
from vnhc_gym.mechanics.functional_fleet import FleetSystem
from vnhc_gym.systems import flocking_system, make_flocking, make_usv
from vnhc_gym.systems.flocking import MAX_AGENTS, flocking_layout


@cache
def written_out(n_agents: int) -> ConstrainedSystem:
    """The whole flock derived and lambdified as one system (no fleet)."""
    return ConstrainedSystem(*flocking_system(n_agents))


def flock_states(rng: np.random.Generator, n: int, batch: int, gap: tuple[float, float] = (1.0, 3.0)) -> np.ndarray:
    """Random states with the leader's xd_N - zd_N = +-[gap], so C = diag((xd_N - zd_N)/m_b) is far from 0."""
    s = rng.uniform(-3, 3, (batch, 4 * n))
    s[:, :2 * n] *= 10
    s[:, 4 * n - 1] = s[:, 3 * n - 1] - rng.choice([-1.0, 1.0], batch) * rng.uniform(*gap, batch)
    return s


def flock_params(rng: np.random.Generator, n: int, batch: int) -> np.ndarray:
    return np.column_stack([rng.uniform(0.5, 4, (batch, n)), rng.uniform(5, 15, batch)])


def assert_close(a: tuple | np.ndarray, b: tuple | np.ndarray) -> None:
    for x, y in zip(a if isinstance(a, tuple) else (a,), b if isinstance(b, tuple) else (b,), strict=True):
        np.testing.assert_allclose(x, y, rtol=1e-12, atol=1e-12)


# --------------------------------------------------------------------------- the fleet is the written-out system


@pytest.mark.parametrize("n", [2, 6])  # one unit, and several (the code is the same for any n)
def test_fleet_metadata_equals_written_out_system(n: int) -> None:
    fleet, full = make_flocking(n), written_out(n)
    assert isinstance(fleet.functions, FleetSystem) and not isinstance(full.functions, FleetSystem)
    for attr in ("name", "n", "m", "n_gains", "holonomic", "param_names", "output_names"):
        assert getattr(fleet, attr) == getattr(full, attr), attr
    np.testing.assert_array_equal(fleet.default_params, full.default_params)
    assert fleet.functions.R == n - 1  # n - 1 copies of the two-particle unit


# One unit, and two (the code is the same for any number of copies; the written-out system of six
# agents compiles for seconds per call).
@pytest.mark.parametrize("n", [2, 3])
@pytest.mark.parametrize("feedback", ["open", "continuous", "sampled"])
def test_fleet_step_equals_written_out_system(n: int, feedback: str) -> None:
    """The same numbers up to rounding (the copies and the written-out expressions are evaluated in
    different orders), and the same flags."""
    fleet, full = make_flocking(n), written_out(n)
    rng = np.random.default_rng(10 * n + len(feedback))
    b = 40
    s = flock_states(rng, n, b)
    s[3, 4 * n - 1] = s[3, 3 * n - 1]  # one row with a singular C (flagged by both)
    p = flock_params(rng, n, b)
    k = rng.uniform(0, 3, (b, n - 1))
    u = rng.normal(scale=5.0, size=(b, n - 1))
    # Several RK4 substeps and bounds on the force that bind on some rows: every part of a step.
    got = fleet.step(s, 0.05, u=u, feedback=feedback, gains=k, params=p, substeps=3, u_bounds=(-8.0, 6.0))
    want = full.step(s, 0.05, u=u, feedback=feedback, gains=k, params=p, substeps=3, u_bounds=(-8.0, 6.0))
    assert_close(got, want)
    flags = got[2]
    assert not np.delete(flags, 3).any()
    assert bool(flags[3] & FLAG_SINGULAR) == (feedback != "open")  # only the law meets C
    # With a told model p_law different from the true p (the law reads p_law, the dynamics p).
    pl = p * rng.uniform(0.7, 1.3, p.shape)
    outs = []
    for model in (fleet, full):
        def one(x, q, q_law, force, g, functions=model.functions):
            return F.rk4_step_controlled(functions, x, q, force, 0.02, 2, feedback=feedback, p_law=q_law, gains=g,
                                         singular_tol=1e-10)

        with jax.enable_x64(True):
            outs.append(tuple(np.asarray(a) for a in jax.vmap(one)(s, p, pl, u, k)))
    assert_close(outs[0], outs[1])
    assert np.abs(outs[0][0] - fleet.step(s, 0.02, u=u, feedback=feedback, gains=k, params=p, substeps=2)[0]).max() \
        > 1e-6 or feedback == "open"  # the told model matters


@pytest.mark.parametrize("n", [2, 6])  # one unit, and several (the code is the same for any n)
def test_fleet_law_and_pieces_equal_written_out_system(n: int) -> None:
    fleet, full = make_flocking(n), written_out(n)
    rng = np.random.default_rng(500 + n)
    b = 40
    s = flock_states(rng, n, b)
    p = flock_params(rng, n, b)
    k = rng.uniform(0, 3, (b, n - 1))
    assert_close(fleet.phi(s, p), full.phi(s, p))
    assert_close(fleet.control(s, k, p), full.control(s, k, p))
    assert_close(fleet.invariance_control(s, p), full.invariance_control(s, p))
    assert_close(fleet.decoupling(s, p), full.decoupling(s, p))
    assert_close(fleet.dynamics(s, p), full.dynamics(s, p))
    assert_close(fleet.outputs(s, p), full.outputs(s, p))
    assert_close(fleet.transversality(s, p), full.transversality(s, p))
    # Energy: the fleet sums its units and removes the leader counted n - 2 times too often, so it
    # is the same number up to rounding; relative to the size of the terms of the sum.
    xd, zd, z = s[:, 2 * n:3 * n], s[:, 3 * n:], s[:, n:2 * n]
    m, g = p[:, :n], p[:, n:]
    size = np.sum(m * (xd**2 + zd**2) / 2 + np.abs(m * g * z), axis=1)
    assert np.all(np.abs(fleet.energy(s, p) - full.energy(s, p)) <= 1e-12 * size)
    # Non-finite states are flagged alike.
    bad = s[:2].copy()
    bad[0, 0] = np.nan
    f_flags, w_flags = fleet.step(bad, 0.01)[2], full.step(bad, 0.01)[2]
    np.testing.assert_array_equal(f_flags, w_flags)
    assert f_flags[0] & FLAG_NONFINITE and not f_flags[1]


def test_fleet_symbolic_side_is_the_written_out_system() -> None:
    fleet = make_flocking(3)
    assert fleet.system.name == "flocking3" and fleet.system.n == 6 and fleet.system.m == 2
    law = fleet.symbolic
    xd3, zd3 = sp.symbols("xd_3 zd_3", real=True)
    m1 = sp.Symbol("m_1", positive=True)
    assert sp.simplify(law.C[0, 0] - (xd3 - zd3) / m1) == 0
    assert law.C[0, 1] == 0 and law.C[1, 0] == 0


# --------------------------------------------------------------------------- any size up to MAX_AGENTS


@pytest.mark.parametrize("n", [2, 10, 100, 1000])
def test_flock_of_any_size_builds_and_steps(n: int) -> None:
    model = make_flocking(n)
    assert (model.n, model.m, model.n_gains) == (2 * n, n - 1, n - 1)
    assert len(model.param_names) == n + 1 and model.param_names[-1] == "g"
    rng = np.random.default_rng(n)
    s = flock_states(rng, n, 2)
    for feedback in ("open", "continuous", "sampled"):
        out, u, flags = model.step(s, 0.01, feedback=feedback)
        assert np.all(np.isfinite(out)) and np.all(np.isfinite(u)) and not flags.any()
    # The free fall of the leader is exact (a quadratic in t): zd_N(dt) = zd_N - g dt.
    np.testing.assert_allclose(out[:, 4 * n - 1], s[:, 4 * n - 1] - 10.0 * 0.01, rtol=1e-14)


def test_flock_size_limits() -> None:
    assert MAX_AGENTS == 1000
    for bad in (1, 0, 2.5, MAX_AGENTS + 1):
        with pytest.raises(ValueError, match="n_agents"):
            make_flocking(bad)  # type: ignore[arg-type]


def test_hundred_agent_flock_decays_exponentially() -> None:
    """Theorem 2 under continuous feedback: phi^b(t) = exp(-k_b t) phi^b(0), each follower its own gain."""
    n, b = 100, 2
    model = make_flocking(n)
    rng = np.random.default_rng(2024)
    s0 = np.empty((b, 4 * n))
    s0[:, :2 * n] = rng.uniform(-50, 50, (b, 2 * n))
    # The leader: xd_N - zd_N >= 1, and it only grows as the leader falls (zd_N decreases): C stays far from 0.
    xd_n, zd_n = np.array([1.5, -0.5]), np.array([-0.5, -2.0])
    # Followers off the manifold: phi^b(0) = xd_N zd_b - xd_b zd_N = +-[0.2, 1], solved for xd_b.
    phi0 = rng.choice([-1.0, 1.0], (b, n - 1)) * rng.uniform(0.2, 1.0, (b, n - 1))
    zd = rng.uniform(-2, 2, (b, n - 1))
    s0[:, 2 * n:3 * n] = np.column_stack([(xd_n[:, None] * zd - phi0) / zd_n[:, None], xd_n])
    s0[:, 3 * n:] = np.column_stack([zd, zd_n])
    np.testing.assert_allclose(model.phi(s0), phi0, rtol=1e-12)
    gains = rng.uniform(0.5, 3.0, n - 1)
    tr = simulate(model, s0, 0.01, 200, feedback="continuous", gains=gains, record_every=10)
    assert not np.any(tr.flags)
    ratio = tr.phi / tr.phi[0]
    expected = np.broadcast_to(np.exp(-tr.t[:, None, None] * gains[None, None, :]), ratio.shape)
    # RK4's local error is O((k dt)^5) per step and does not shrink with phi: relative while
    # exp(-k t) is not tiny, then an absolute floor.
    np.testing.assert_array_less(np.abs(ratio - expected), 1e-5 * (expected + 1e-2))
    assert np.all(np.abs(tr.phi[-1]) < 0.37 * np.abs(tr.phi[0]))  # at least exp(-0.5 * 2) of decay by t = 2 s


# --------------------------------------------------------------------------- the layout


def _layout(**changes: object) -> FleetLayout:
    base = flocking_layout(3)  # copies (follower b, leader): unit coordinates (x_f, x_l, z_f, z_l)
    fields = {"name": "test_fleet", "n": base.n, "state_map": base.state_map.copy(), "param_map": base.param_map,
              "own": base.own, "param_names": base.param_names, "param_defaults": base.param_defaults}
    fields.update(changes)
    return FleetLayout(**fields)  # type: ignore[arg-type]


def test_flocking_layout_is_what_the_module_says() -> None:
    layout = flocking_layout(3)
    # State (x_1, x_2, x_3, z_1, z_2, z_3, xd_1, ..., zd_3); copy b = follower b + the leader (particle 3).
    np.testing.assert_array_equal(layout.state_map, [[0, 2, 3, 5, 6, 8, 9, 11], [1, 2, 4, 5, 7, 8, 10, 11]])
    np.testing.assert_array_equal(layout.param_map, [[0, 2, 3], [1, 2, 3]])  # (m_b, m_3, g)
    assert layout.replicas == 2 and layout.param_names == ("m_1", "m_2", "m_3", "g")


def test_layout_rejects_shared_coordinates_mapped_differently_per_copy() -> None:
    sm = flocking_layout(3).state_map.copy()
    sm[1, 1] = 1  # copy 1's "leader x" is now follower 2's x
    with pytest.raises(ValueError, match="shared unit coordinates"):
        _layout(state_map=sm)


def test_layout_rejects_overlapping_own_entries() -> None:
    sm = flocking_layout(3).state_map.copy()
    sm[1, 0] = sm[0, 0]  # both copies own x_1 (and nobody owns x_2)
    with pytest.raises(ValueError, match="exactly one copy"):
        _layout(state_map=sm)
    with pytest.raises(ValueError, match="exactly one copy"):  # x_4 etc. belong to nobody
        _layout(n=7, state_map=flocking_layout(3).state_map)


def test_layout_rejects_bad_shapes_and_indices() -> None:
    sm = flocking_layout(3).state_map
    with pytest.raises(ValueError, match="state_map"):
        _layout(state_map=sm[:, :6])
    with pytest.raises(ValueError, match="param_map"):
        _layout(param_map=np.zeros((3, 3), dtype=np.int64))
    with pytest.raises(ValueError, match="param_defaults"):
        _layout(param_defaults=(2.0,))
    for bad in (-1, 12):
        s2 = sm.copy()
        s2[0, 0] = bad
        with pytest.raises(ValueError, match="outside"):
            _layout(state_map=s2)
    with pytest.raises(ValueError, match="outside"):
        _layout(param_map=np.array([[0, 2, 4], [1, 2, 3]]))


def test_layout_rejects_velocities_not_at_their_coordinates() -> None:
    sm = flocking_layout(3).state_map.copy()
    sm[[0, 1], 4] = sm[[1, 0], 4]  # copy 0's xd is follower 2's, copy 1's is follower 1's
    with pytest.raises(ValueError):
        _layout(state_map=sm)


def test_fleet_rejects_a_layout_that_does_not_fit_its_unit() -> None:
    unit_model = make_flocking(2)
    narrow = _layout(name="narrow", param_map=flocking_layout(3).param_map[:, :2])  # the unit has 3 parameters
    with pytest.raises(ValueError):
        ConstrainedSystem.fleet(unit_model, narrow)


# --------------------------------------------------------------------------- the unit's shared part must be autonomous


def _unit(kind: str) -> MechanicalSystem:
    """A follower x and a shared leader y on a line; the control pushes the follower."""
    x, y, xd, yd = sp.symbols("x y xd yd", real=True)
    m, mass_l, k = sp.symbols("m M k", positive=True)
    forces = sp.Matrix([1, 1 if kind == "control" else 0])
    potential = k * (x - y) ** 2 / 2 if kind == "spring" else sp.Integer(0)
    drag = sp.Matrix([0, -xd]) if kind == "drag" else None
    return MechanicalSystem(name=f"test_unit_{kind}", q=(x, y), qd=(xd, yd), mass_matrix=sp.diag(m, mass_l),
                            control_forces=forces, potential=potential, external_force=drag,
                            params={m: 1.0, mass_l: 2.0, k: 3.0})


def _law(kind: str):
    system = _unit(kind)
    return derive_law(system, VelocityConstraint(sp.Matrix([system.qd[0] - system.qd[1]])))


def test_check_autonomous_accepts_a_free_shared_coordinate() -> None:
    assert check_autonomous(_law("free"), np.array([True, False])) is None
    # With nothing shared there is nothing to check.
    assert check_autonomous(_law("spring"), np.array([True, True])) is None


@pytest.mark.parametrize("kind, message", [("spring", "driven by the copies' own coordinates"),
                                           ("drag", "driven by the copies' own coordinates"),
                                           ("control", "moved by a control")])
def test_check_autonomous_rejects_a_driven_shared_coordinate(kind: str, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        check_autonomous(_law(kind), np.array([True, False]))


def test_fleet_of_a_non_autonomous_unit_is_refused() -> None:
    system = _unit("control")
    unit = ConstrainedSystem(system, VelocityConstraint(sp.Matrix([system.qd[0] - system.qd[1]])))
    # Two copies (followers 0 and 1) sharing the leader 2; unit parameters (m, M, k) shared too.
    layout = FleetLayout("test_fleet_bad", 3, np.array([[0, 2, 3, 5], [1, 2, 4, 5]]),
                         np.array([[0, 1, 2], [0, 1, 2]]), np.array([True, False]), ("m", "M", "k"), (1.0, 2.0, 3.0))
    with pytest.raises(ValueError, match="moved by a control"):
        ConstrainedSystem.fleet(unit, layout)


def test_the_flock_unit_is_autonomous() -> None:
    """The flock's followers share the leader, which falls freely: what makes the fleet exact."""
    unit = make_flocking(2)
    assert check_autonomous(unit.symbolic, flocking_layout(3).own) is None


# --------------------------------------------------------------------------- the singular test is scale-free


@pytest.mark.parametrize("mass", [1e-10, 1.0, 1e10])
def test_usv_law_is_regular_at_any_mass(mass: float) -> None:
    """The USV's C = 1/m is never singular: a huge mass (C = 1e-10) must not be taken for C = 0."""
    model = make_usv("northeast")
    params = model.params(m=mass)
    rng = np.random.default_rng(7)
    s = np.column_stack([rng.uniform(-3, 3, (8, 2)), rng.uniform(-np.pi, np.pi, 8), rng.uniform(-2, 2, (8, 3))])
    c, _ = model.decoupling(s, params)
    np.testing.assert_allclose(c[:, 0, 0], 1.0 / mass, rtol=1e-15)
    u, singular = model.control(s, gains=2.0, params=params, on_singular="flag")
    assert not singular.any() and np.all(np.isfinite(u))
    # By hand (the current (1, 1) cancels from G): u* = -m [k phi + thetad (xd cos + yd sin)].
    x, y, th, xd, yd, thd = s.T
    phi = np.sin(th) * (xd - 1.0) - np.cos(th) * (yd - 1.0)
    np.testing.assert_allclose(u[:, 0], -mass * (2.0 * phi + thd * (xd * np.cos(th) + yd * np.sin(th))),
                               rtol=1e-10, atol=1e-12 * mass)
    assert not model.step(s, 0.01, feedback="continuous", params=params)[2].any()


@cache
def plane() -> ConstrainedSystem:
    """A particle in a plane held to rest, pushed along (1, x) and (1, 1): C = [[1, 1], [x, 1]] / m,
    a full 2x2 decoupling matrix, singular exactly at x = 1."""
    x, y, xd, yd = sp.symbols("x y xd yd", real=True)
    m = sp.Symbol("m", positive=True)
    system = MechanicalSystem(name="test_plane", q=(x, y), qd=(xd, yd), mass_matrix=m * sp.eye(2),
                              control_forces=sp.Matrix([[1, 1], [x, 1]]), params={m: 1.0})
    return ConstrainedSystem(system, VelocityConstraint(sp.Matrix([xd, yd])))


@pytest.mark.parametrize("mass", [1e-12, 1.0, 1e12])
def test_full_decoupling_matrix_singular_at_any_scale(mass: float) -> None:
    model = plane()
    s = np.array([[0.0, 0.0, 0.3, -0.7],  # x = 0: det = 1 - x = 1
                  [1.0, 0.0, 0.3, -0.7],  # x = 1: singular
                  [3.0, 5.0, -1.0, 2.0]])
    c, g = model.decoupling(s, [mass])
    np.testing.assert_allclose(c[0], np.array([[1.0, 1.0], [0.0, 1.0]]) / mass, rtol=1e-15)
    assert np.all(g == 0.0)
    u, singular = model.control(s, gains=1.5, params=[mass], on_singular="flag")
    assert singular.tolist() == [False, True, False]
    # By hand: C u = -K phi with phi = qd, so u = -1.5 m F^-1 qd with F = [[1, 1], [x, 1]].
    for row in (0, 2):
        f = np.array([[1.0, 1.0], [s[row, 0], 1.0]])
        np.testing.assert_allclose(u[row], -1.5 * mass * np.linalg.solve(f, s[row, 2:]), rtol=1e-13)
    np.testing.assert_array_equal(u[1], [0.0, 0.0])
    with pytest.raises(SingularControlError) as info:
        model.control(s, params=[mass])
    assert info.value.rows.tolist() == [1]
    flags = model.step(s, 0.01, feedback="continuous", params=[mass])[2]
    assert (flags & FLAG_SINGULAR).astype(bool).tolist() == [False, True, False]
