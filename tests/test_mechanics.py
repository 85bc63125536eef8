"""Acceptance tests of the geometric core (``vnhc_gym.mechanics``) on problems with known answers.

Every expected value here comes from an independent fact (an exact ODE solution, a hand-derived
formula, a defining identity), never from the library's own output.
"""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest
import sympy as sp
from hypothesis import given, settings
from hypothesis import strategies as st

from vnhc_gym.mechanics import (
    FEEDBACK_MODES,
    FLAG_NONFINITE,
    FLAG_SINGULAR,
    ConstrainedSystem,
    HolonomicConstraint,
    MechanicalSystem,
    SingularControlError,
    Trajectory,
    VelocityConstraint,
    derive_law,
    sampled_control,
    simulate,
)
from vnhc_gym.systems import make_flocking

# --------------------------------------------------------------------------- test systems


def _oscillator_system() -> tuple[MechanicalSystem, VelocityConstraint]:
    x, xd = sp.symbols("x xd", real=True)
    k = sp.Symbol("k", positive=True)
    system = MechanicalSystem(name="test_oscillator", q=(x,), qd=(xd,), mass_matrix=sp.Matrix([[1]]),
                              control_forces=sp.Matrix([[1]]), potential=k * x**2 / 2, params={k: 4.0})
    return system, VelocityConstraint(sp.Matrix([xd]))


@cache
def oscillator() -> ConstrainedSystem:
    """x'' = -k x + u, k = 4 (omega = 2); constraint phi = xd."""
    return ConstrainedSystem(*_oscillator_system())


@cache
def circle() -> ConstrainedSystem:
    """Unit-mass particle in a vertical plane under gravity, pushed radially, held to x^2 + y^2 = R^2."""
    x, y, xd, yd = sp.symbols("x y xd yd", real=True)
    g, radius = sp.symbols("g R", positive=True)
    system = MechanicalSystem(name="test_circle", q=(x, y), qd=(xd, yd), mass_matrix=sp.eye(2),
                              control_forces=sp.Matrix([x, y]), potential=g * y, params={g: 9.81, radius: 1.5})
    return ConstrainedSystem(system, HolonomicConstraint(sp.Matrix([x**2 + y**2 - radius**2])))


# --------------------------------------------------------------------------- RK4 against exact solutions


def _oscillator_error(dt: float, t_end: float = 2.0) -> tuple[float, float]:
    model = oscillator()
    omega = 2.0
    s0 = np.array([0.7, -1.1])
    tr = simulate(model, s0, dt, round(t_end / dt), feedback="open")
    assert tr.t[-1] == pytest.approx(t_end)
    exact = np.array([s0[0] * np.cos(omega * t_end) + s0[1] / omega * np.sin(omega * t_end),
                      -s0[0] * omega * np.sin(omega * t_end) + s0[1] * np.cos(omega * t_end)])
    energy0 = 0.5 * s0[1] ** 2 + 0.5 * omega**2 * s0[0] ** 2  # E = xd^2/2 + k x^2/2, by hand
    return float(np.max(np.abs(tr.states[-1] - exact))), float(np.max(np.abs(tr.energy - energy0)))


def test_rk4_is_fourth_order_on_harmonic_oscillator() -> None:
    errs = [_oscillator_error(dt) for dt in (0.1, 0.05, 0.025)]
    state_err = [e[0] for e in errs]
    assert state_err[0] < 1e-3  # actually converging to the exact solution, not just self-consistent
    for coarse, fine in zip(state_err, state_err[1:], strict=False):
        assert 13.0 < coarse / fine < 19.0


def test_rk4_conserves_oscillator_energy_to_fourth_order() -> None:
    dts = (0.1, 0.05, 0.025)
    energy_err = [_oscillator_error(dt)[1] for dt in dts]
    energy0 = 0.5 * 1.1**2 + 0.5 * 4.0 * 0.7**2
    for dt, err in zip(dts, energy_err, strict=True):
        assert err < energy0 * (2.0 * dt) ** 4  # O(dt^4): relative drift below (omega dt)^4
    for coarse, fine in zip(energy_err, energy_err[1:], strict=False):
        assert coarse / fine > 13.0  # at least fourth order


def test_rk4_energy_follows_stability_polynomial() -> None:
    # In the coordinates (omega x, xd) the oscillator is a rotation, and one RK4 step is the
    # normal matrix R(h A) with R(z) = 1 + z + z^2/2 + z^3/6 + z^4/24; so the energy is
    # multiplied by |R(i omega h)|^2 = 1 - (omega h)^6/72 + (omega h)^8/576 at every step.
    model = oscillator()
    s0 = np.array([0.7, -1.1])
    dt, n = 0.1, 40
    tr = simulate(model, s0, dt, n, feedback="open")
    z = 2.0 * dt
    factor = 1 - z**6 / 72 + z**8 / 576
    energy0 = 0.5 * s0[1] ** 2 + 0.5 * 4.0 * s0[0] ** 2
    np.testing.assert_allclose(tr.energy, energy0 * factor ** np.arange(n + 1), rtol=1e-13)


def test_energy_matches_hand_formula() -> None:
    model = oscillator()
    rng = np.random.default_rng(3)
    s = rng.normal(size=(7, 2))
    params = np.array([2.5])
    np.testing.assert_allclose(model.energy(s, params), 0.5 * s[:, 1] ** 2 + 0.5 * 2.5 * s[:, 0] ** 2, rtol=1e-14)


def test_open_loop_free_fall_is_exact() -> None:
    # Ballistic motion is a quadratic in t, which RK4 integrates exactly.
    model = make_flocking(4)
    rng = np.random.default_rng(4)
    s0 = rng.uniform(-5, 5, 16)
    g, t_end = 10.0, 1.3
    tr = simulate(model, s0, 0.01, 130, feedback="open")
    pos, vel = s0[:8], s0[8:]
    accel = np.r_[np.zeros(4), -g * np.ones(4)]
    np.testing.assert_allclose(tr.states[-1, :8], pos + vel * t_end + 0.5 * accel * t_end**2, rtol=1e-12, atol=1e-11)
    np.testing.assert_allclose(tr.states[-1, 8:], vel + accel * t_end, rtol=1e-12, atol=1e-11)


def test_open_loop_control_is_held() -> None:
    # Constant push u on the follower 1 of a flocking system: xdd_1 = u/m_1, zdd_1 = u/m_1 - g.
    model = make_flocking(4)
    s0 = np.zeros(16)
    u = np.array([3.0, 0.0, 0.0])
    tr = simulate(model, s0, 0.02, 50, feedback="open", u=u)
    t = 1.0
    assert tr.states[-1, 0] == pytest.approx(0.5 * 1.5 * t**2, rel=1e-12)
    assert tr.states[-1, 4] == pytest.approx(0.5 * (1.5 - 10.0) * t**2, rel=1e-12)
    np.testing.assert_allclose(tr.u, np.broadcast_to(u, tr.u.shape))


def _rk4_polynomial(z: np.ndarray) -> np.ndarray:
    """RK4's stability polynomial of a matrix: one step of y' = A y is exactly y -> R(hA) y."""
    eye = np.eye(z.shape[0])
    return eye + z + z @ z / 2 + z @ z @ z / 6 + z @ z @ z @ z / 24


def _rk4_input_polynomial(z: np.ndarray) -> np.ndarray:
    """One RK4 step of y' = A y + c adds h P(hA) c, with P(z) = 1 + z/2 + z^2/6 + z^3/24."""
    eye = np.eye(z.shape[0])
    return eye + z / 2 + z @ z / 6 + z @ z @ z / 24


def _oscillator_rk4(mode: str, s: np.ndarray, k_true: float, k_told: float, gain: float, dt: float, substeps: int,
                    u_held: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    import jax

    from vnhc_gym.mechanics import functional as F

    model = oscillator()

    def one(x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return F.rk4_step_controlled(model.functions, x, np.array([k_true]), np.array([u_held]), dt, substeps,
                                     feedback=mode, p_law=np.array([k_told]), gains=np.array([gain]),
                                     singular_tol=1e-10)

    with jax.enable_x64(True):
        out, u_out, singular = jax.vmap(one)(s)
        return np.asarray(out), np.asarray(u_out)[:, 0], np.asarray(singular)


def test_continuous_feedback_step_is_rk4_of_the_linear_closed_loop() -> None:
    """The oscillator's law is linear, u* = -K xd + k_told x (with the told model), so the closed loop
    y' = A y, A = [[0, 1], [k_told - k_true, -K]], is linear and an RK4 step is exactly R(h A).
    The dynamics use the true k (p) and the law the told one (p_law)."""
    s = np.array([[0.7, -1.1], [-2.0, 0.4], [0.0, 1.0]])
    k_true, k_told, gain, dt, substeps = 4.0, 2.5, 1.7, 0.1, 2
    out, u_out, flags = _oscillator_rk4("continuous", s, k_true, k_told, gain, dt, substeps)
    a = np.array([[0.0, 1.0], [k_told - k_true, -gain]])
    step = _rk4_polynomial(dt / substeps * a)
    mid = s @ step.T
    np.testing.assert_allclose(out, mid @ step.T, rtol=1e-14, atol=1e-15)
    # u_out: the mean over the substeps of the control at each substep's first stage.
    law = np.array([k_told, -gain])
    np.testing.assert_allclose(u_out, (s @ law + mid @ law) / 2, rtol=1e-14, atol=1e-15)
    assert not flags.any()
    # The told model matters: with k_told = k_true the closed loop is xd' = -K xd.
    out_exact, _, _ = _oscillator_rk4("continuous", s, k_true, k_true, gain, dt, 1)
    np.testing.assert_allclose(out_exact[:, 1], s[:, 1] * _rk4_polynomial(np.array([[-gain * dt]]))[0, 0],
                               rtol=1e-14)
    assert np.max(np.abs(out_exact - out)) > 1e-3


@pytest.mark.parametrize("mode", ["sampled", "open"])
def test_held_control_step_is_rk4_of_the_affine_system(mode: str) -> None:
    """With the control held over the period (sampled: u*(start) + u; open: u) the system is
    y' = B y + (0, u), B = [[0, 1], [-k_true, 0]]: one RK4 step is R(hB) y + h P(hB) (0, u)."""
    s = np.array([[0.7, -1.1], [-2.0, 0.4]])
    k_true, k_told, gain, dt, held = 4.0, 2.5, 1.7, 0.05, 0.3
    out, u_out, flags = _oscillator_rk4(mode, s, k_true, k_told, gain, dt, 1, u_held=held)
    u = held + (-gain * s[:, 1] + k_told * s[:, 0] if mode == "sampled" else 0.0)
    z = dt * np.array([[0.0, 1.0], [-k_true, 0.0]])
    expected = s @ _rk4_polynomial(z).T + dt * np.outer(u, _rk4_input_polynomial(z)[:, 1])
    np.testing.assert_allclose(out, expected, rtol=1e-14, atol=1e-15)
    np.testing.assert_allclose(u_out, u, rtol=1e-15)
    assert not flags.any()


# --------------------------------------------------------------------------- holonomic constraint (Remark 2)


def _second_order_solution(k1: float, k2: float, a: np.ndarray, b: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Solution of y'' + k2 y' + k1 y = 0 with y(0) = a, y'(0) = b (critically or under-damped)."""
    t = t[:, None]
    disc = k2**2 - 4 * k1
    if disc == 0:
        lam = -k2 / 2
        return (a + (b - lam * a) * t) * np.exp(lam * t)
    assert disc < 0
    sigma, omega = -k2 / 2, np.sqrt(-disc) / 2
    return np.exp(sigma * t) * (a * np.cos(omega * t) + (b - sigma * a) / omega * np.sin(omega * t))


@pytest.mark.parametrize("gains", [(4.0, 4.0), (5.0, 2.0)])
def test_holonomic_constraint_follows_second_order_ode(gains: tuple[float, float]) -> None:
    model = circle()
    radius = 1.5
    rng = np.random.default_rng(5)
    b = 12
    r = radius + rng.uniform(-0.4, 0.4, b)
    ang = rng.uniform(0, 2 * np.pi, b)
    s0 = np.column_stack([r * np.cos(ang), r * np.sin(ang), rng.uniform(-1, 1, (b, 2))])
    tr = simulate(model, s0, 0.01, 500, feedback="continuous", gains=gains, record_every=5)
    assert not np.any(tr.flags)
    # Independent values of phi_h and its derivative at t = 0, from the definition.
    a0 = s0[:, 0] ** 2 + s0[:, 1] ** 2 - radius**2
    b0 = 2 * (s0[:, 0] * s0[:, 2] + s0[:, 1] * s0[:, 3])
    expected = _second_order_solution(*gains, a0, b0, tr.t)
    states = tr.states.reshape(-1, 4)
    phi_h = model.phi_h(states).reshape(len(tr.t), b)
    np.testing.assert_allclose(phi_h, expected, rtol=0, atol=1e-6)
    assert np.max(np.abs(phi_h[-1])) < 1e-2 * np.max(np.abs(a0))  # and it has actually converged


def test_holonomic_pieces_by_hand() -> None:
    model = circle()
    assert model.holonomic and model.n_gains == 2
    rng = np.random.default_rng(6)
    s = rng.normal(size=(9, 4))
    x, y, xd, yd = s.T
    params = np.array([3.0, 0.8])
    np.testing.assert_allclose(model.phi_h(s, params)[:, 0], x**2 + y**2 - 0.64, rtol=1e-13)
    np.testing.assert_allclose(model.phi(s, params)[:, 0], 2 * (x * xd + y * yd), rtol=1e-13)
    c, g = model.decoupling(s, params)
    # psi = 2 (x xd + y yd); Y = (x, y); a0 = (0, -g): C = 2 (x^2 + y^2), G = 2 (xd^2 + yd^2) - 2 g y.
    np.testing.assert_allclose(c[:, 0, 0], 2 * (x**2 + y**2), rtol=1e-13)
    np.testing.assert_allclose(g[:, 0], 2 * (xd**2 + yd**2) - 2 * 3.0 * y, rtol=1e-12, atol=1e-13)


def test_holonomic_constraint_rejects_velocities() -> None:
    system, _ = _oscillator_system()
    with pytest.raises(ValueError, match="phi_h"):
        derive_law(system, HolonomicConstraint(sp.Matrix([system.qd[0]])))


def test_phi_h_only_for_holonomic() -> None:
    with pytest.raises(ValueError, match="phi_h"):
        oscillator().phi_h(np.zeros(2))


# --------------------------------------------------------------------------- the law's defining identity


def test_closed_loop_oscillator_phi_decays_exactly() -> None:
    # phi = xd, so u* = -k_gain xd + k x: the closed loop gives xd(t) = xd(0) exp(-k_gain t).
    model = oscillator()
    s0 = np.array([[0.3, 1.2], [-2.0, -0.4]])
    x, xd = s0.T
    np.testing.assert_allclose(model.control(s0, gains=1.7)[:, 0], -1.7 * xd + 4.0 * x, rtol=1e-14)
    tr = simulate(model, s0, 0.01, 300, gains=1.7)
    np.testing.assert_allclose(tr.phi[:, :, 0], xd * np.exp(-1.7 * tr.t)[:, None], rtol=1e-8)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), batch=st.integers(1, 9))
def test_control_satisfies_defining_identity(seed: int, batch: int) -> None:
    """u* solves C u = -K phi - G, with C, G from ``decoupling`` (flocking and a non-diagonal C)."""
    rng = np.random.default_rng(seed)
    for model in (make_flocking(4), circle()):
        s = rng.uniform(-3, 3, (batch, 2 * model.n))
        if not model.holonomic:  # flocking: keep C = diag((xd_4 - zd_4)/m_b) away from 0
            s[:, 15] = s[:, 11] - rng.choice([-1, 1], batch) * rng.uniform(0.5, 3, batch)
        k = rng.uniform(0, 3, (batch, model.n_gains))
        c, g = model.decoupling(s)
        u = model.control(s, gains=k)
        lhs = np.einsum("bij,bj->bi", c, u)
        if model.holonomic:
            rhs = -k[:, :1] * model.phi_h(s) - k[:, 1:] * model.phi(s) - g
        else:
            rhs = -k * model.phi(s) - g
        np.testing.assert_allclose(lhs, rhs, rtol=1e-9, atol=1e-9 * (1 + np.abs(rhs).max()))


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), batch=st.integers(1, 12))
def test_batched_evaluation_equals_row_by_row(seed: int, batch: int) -> None:
    model = make_flocking(4)
    rng = np.random.default_rng(seed)
    s = rng.uniform(-10, 10, (batch, 16))
    s[:, 15] = s[:, 11] + rng.uniform(0.5, 3, batch)
    p = rng.uniform(0.5, 5, (batch, 5))
    phi = model.phi(s, p)
    u = model.control(s, gains=2.0, params=p)
    energy = model.energy(s, p)
    for r in range(batch):
        np.testing.assert_array_equal(phi[r], model.phi(s[r], p[r]))
        np.testing.assert_array_equal(u[r], model.control(s[r], gains=2.0, params=p[r]))
        assert energy[r] == model.energy(s[r], p[r])


def test_sampled_feedback_is_zero_order_hold() -> None:
    # Sampled mode must equal: evaluate u* at the start, then integrate open loop with it held.
    model = make_flocking(4)
    rng = np.random.default_rng(8)
    s = rng.uniform(-3, 3, (5, 16))
    s[:, 15] = s[:, 11] - 1.5
    u_star = model.control(s, gains=0.7)
    sampled, u_applied, flags = model.step(s, 0.05, feedback="sampled", gains=0.7, substeps=3)
    held, _, _ = model.step(s, 0.05, feedback="open", u=u_star, substeps=3)
    np.testing.assert_allclose(sampled, held, rtol=1e-14, atol=1e-14)
    np.testing.assert_allclose(u_applied, u_star, rtol=1e-14)
    assert not flags.any()


def test_sampled_control_meets_the_discrete_decay_and_measures_the_increment() -> None:
    """The sampled-data law on the boat: the held force makes phi after one period exp(-K dt) times
    phi now (to rounding), and with a measured phi_now the model gives the increment,
    phi(F(x, u)) - phi(x) = (exp(-K dt) - 1) phi_now.  With no Newton step it is u* itself."""
    from vnhc_gym.systems import make_usv

    model = make_usv()
    rng = np.random.default_rng(3)
    s = rng.uniform(-0.5, 0.5, (4, 6))
    dt, gain, sub = 0.1, 20.0, 4
    u, converged = sampled_control(model, s, None, dt, gain, sub, iters=6)
    assert converged.all()
    end, _, _ = model.step(s, dt, u=u, substeps=sub)
    np.testing.assert_allclose(model.phi(end), np.exp(-gain * dt) * model.phi(s), rtol=0, atol=1e-13)
    measured = 0.5 * model.phi(s)
    u2, converged = sampled_control(model, s, None, dt, gain, sub, iters=6, phi_now=measured)
    end, _, _ = model.step(s, dt, u=u2, substeps=sub)
    np.testing.assert_allclose(model.phi(end) - model.phi(s), np.expm1(-gain * dt) * measured, rtol=0, atol=1e-13)
    assert converged.all()
    u0, converged = sampled_control(model, s, None, dt, gain, sub, iters=0)
    np.testing.assert_array_equal(u0, model.control(s, gain))
    assert not converged.any()


def test_sampled_control_solves_the_flock_in_one_newton_step() -> None:
    """Held, the flock's motion is a polynomial of degree two in time, which RK4 integrates exactly, so
    the discrete equation is affine in the control: one Newton step from u* solves it."""
    model = make_flocking(4)
    rng = np.random.default_rng(8)
    s = rng.uniform(-3, 3, (5, 16))
    u, _ = sampled_control(model, s, None, 0.05, 10.0, 3, iters=1)
    end, _, _ = model.step(s, 0.05, u=u, substeps=3)
    np.testing.assert_allclose(model.phi(end), np.exp(-10.0 * 0.05) * model.phi(s), rtol=1e-12, atol=1e-12)


def test_u_bounds_saturate_the_control() -> None:
    model = make_flocking(4)
    s = np.zeros(16)
    s[11], s[15] = 1.0, -1.0
    s[8:11] = 5.0  # followers far from aligned: u* is large
    _, u_applied, _ = model.step(s, 0.01, feedback="sampled", u_bounds=(-0.5, 0.5))
    assert np.all(np.abs(u_applied) <= 0.5 + 1e-15)
    assert np.all(np.abs(model.control(s)) > 0.5)


# --------------------------------------------------------------------------- singular decoupling matrix


def _singular_flocking_state() -> np.ndarray:
    s = np.arange(16, dtype=np.float64) / 7.0
    s[11] = s[15] = 0.8  # xd_4 == zd_4: C = diag((xd_4 - zd_4)/m_b) = 0
    return s


def test_singular_control_raises() -> None:
    model = make_flocking(4)
    s = _singular_flocking_state()
    with np.errstate(all="raise"):
        with pytest.raises(SingularControlError) as info:
            model.control(s)
        with pytest.raises(ArithmeticError):
            model.control(s, gains=[1.0, 2.0, 3.0])
        with pytest.raises(SingularControlError):
            model.invariance_control(s)
    assert info.value.rows.tolist() == [0]


def test_singular_control_flag_mode() -> None:
    model = make_flocking(4)
    bad = _singular_flocking_state()
    good = bad.copy()
    good[15] = -0.8
    with np.errstate(all="raise"):
        u, flag = model.control(bad, on_singular="flag")
        assert bool(flag) is True
        assert np.all(np.isfinite(u))
        ub, flags = model.control(np.stack([good, bad, good]), on_singular="flag")
        assert flags.tolist() == [False, True, False]
        assert np.all(np.isfinite(ub))
        with pytest.raises(SingularControlError) as info:
            model.control(np.stack([good, bad, good]))
    assert info.value.rows.tolist() == [1]


def test_singular_step_is_flagged_not_crashed() -> None:
    model = make_flocking(4)
    s = _singular_flocking_state()
    with np.errstate(all="raise"):
        out, u_applied, flags = model.step(s, 0.01, feedback="continuous")
        assert np.all(np.isfinite(out)) and np.all(np.isfinite(u_applied))
        assert flags & FLAG_SINGULAR
        assert not flags & FLAG_NONFINITE
        out_s, _, flags_s = model.step(s, 0.01, feedback="sampled")
        assert np.all(np.isfinite(out_s)) and flags_s & FLAG_SINGULAR
        tr = simulate(model, np.stack([s, s]), 0.01, 3)
    assert np.all(tr.flags & FLAG_SINGULAR)


def test_nonfinite_state_is_flagged() -> None:
    model = make_flocking(4)
    s = np.zeros(16)
    s[0] = np.nan
    _, _, flags = model.step(s, 0.01, feedback="open")
    assert flags & FLAG_NONFINITE


# --------------------------------------------------------------------------- argument checking


@pytest.fixture(scope="module")
def flock() -> ConstrainedSystem:
    return make_flocking(4)


@pytest.mark.parametrize("state", [np.zeros(15), np.zeros((3, 17)), np.zeros((2, 2, 16)), np.zeros(0)])
def test_bad_state_shape(flock: ConstrainedSystem, state: np.ndarray) -> None:
    for call in (flock.phi, flock.energy, flock.control, flock.decoupling, flock.dynamics, flock.outputs):
        with pytest.raises(ValueError, match="state"):
            call(state)
    with pytest.raises(ValueError, match="state"):
        flock.step(state, 0.01)
    with pytest.raises(ValueError, match="state"):
        simulate(flock, state, 0.01, 3)


@pytest.mark.parametrize("dt", [0.0, -0.01, np.nan, np.inf])
def test_bad_dt(flock: ConstrainedSystem, dt: float) -> None:
    with pytest.raises(ValueError, match="dt"):
        flock.step(np.zeros(16), dt)
    with pytest.raises(ValueError, match="dt"):
        simulate(flock, np.zeros(16), dt, 3)


@pytest.mark.parametrize("substeps", [0, -1, 1.5])
def test_bad_substeps(flock: ConstrainedSystem, substeps: float) -> None:
    with pytest.raises(ValueError, match="substeps"):
        flock.step(np.zeros(16), 0.01, substeps=substeps)  # type: ignore[arg-type]


@pytest.mark.parametrize("feedback", ["closed", "Continuous", "", "zoh"])
def test_bad_feedback(flock: ConstrainedSystem, feedback: str) -> None:
    with pytest.raises(ValueError, match="feedback"):
        flock.step(np.zeros(16), 0.01, feedback=feedback)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="feedback"):
        simulate(flock, np.zeros(16), 0.01, 2, feedback=feedback)  # type: ignore[arg-type]


def test_feedback_modes_are_named() -> None:
    assert set(FEEDBACK_MODES) == {"open", "continuous", "sampled"}


@pytest.mark.parametrize("params", [np.ones(4), np.ones(6), np.ones((2, 5)), np.ones((3, 4))])
def test_bad_params(flock: ConstrainedSystem, params: np.ndarray) -> None:
    states = np.zeros((3, 16))
    states[:, 15] = -1.0
    with pytest.raises(ValueError, match="params"):
        flock.phi(states, params)
    with pytest.raises(ValueError, match="params"):
        flock.control(states, params=params)
    with pytest.raises(ValueError, match="params"):
        flock.step(states, 0.01, params=params)


@pytest.mark.parametrize("gains", [[1.0, 2.0], [1.0, -1.0, 1.0], [np.nan, 1.0, 1.0], np.ones((2, 3))])
def test_bad_gains(flock: ConstrainedSystem, gains: object) -> None:
    states = np.zeros((3, 16))
    states[:, 15] = -1.0
    with pytest.raises(ValueError, match="gains"):
        flock.control(states, gains=gains)


def test_bad_simulate_arguments(flock: ConstrainedSystem) -> None:
    with pytest.raises(ValueError, match="n_steps"):
        simulate(flock, np.zeros(16), 0.01, 0)
    with pytest.raises(ValueError, match="record_every"):
        simulate(flock, np.zeros(16), 0.01, 5, record_every=0)
    with pytest.raises(ValueError, match="on_singular"):
        flock.control(np.zeros(16), on_singular="ignore")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="u_bounds"):
        flock.step(np.zeros(16), 0.01, u_bounds=(1.0, -1.0))
    with pytest.raises(ValueError, match="param"):
        flock.params(mass=3.0)


def test_bad_system_definitions() -> None:
    x, xd, y = sp.symbols("x xd y")
    with pytest.raises(ValueError, match="mass_matrix"):
        MechanicalSystem("bad", (x,), (xd,), sp.eye(2), sp.Matrix([[1]]))
    with pytest.raises(ValueError, match="control_forces"):
        MechanicalSystem("bad", (x,), (xd,), sp.eye(1), sp.Matrix([[1], [1]]))
    with pytest.raises(ValueError, match="symbols"):
        MechanicalSystem("bad", (x,), (xd,), sp.eye(1), sp.Matrix([[1]]), potential=y * x)
    system, _ = _oscillator_system()
    with pytest.raises(ValueError, match="controls"):
        derive_law(system, VelocityConstraint(sp.Matrix([system.qd[0], system.qd[0]])))
    with pytest.raises(ValueError, match="singular_tol"):
        ConstrainedSystem(system, VelocityConstraint(sp.Matrix([system.qd[0]])), singular_tol=0.0)


# --------------------------------------------------------------------------- simulate bookkeeping


def test_simulate_records_and_shapes(flock: ConstrainedSystem) -> None:
    s = np.zeros((2, 16))
    s[:, 15] = -1.0
    tr = simulate(flock, s, 0.01, 25, record_every=10)
    assert isinstance(tr, Trajectory)
    np.testing.assert_allclose(tr.t, [0.0, 0.1, 0.2, 0.25])
    assert tr.states.shape == (4, 2, 16) and tr.phi.shape == (4, 2, 3) and tr.u.shape == (3, 2, 3)
    assert tr.energy.shape == (4, 2) and tr.flags.shape == (2,)
    single = simulate(flock, s[0], 0.01, 25, record_every=10)
    assert single.states.shape == (4, 16)
    np.testing.assert_array_equal(single.states, tr.states[:, 0])
    # Each record is the same as stepping that many periods by hand.
    cur = s[0]
    for _ in range(10):
        cur = flock.step(cur, 0.01, feedback="continuous")[0]
    np.testing.assert_array_equal(single.states[1], cur)


@pytest.mark.parametrize("build", ["sled", "circle"])
def test_closed_form_law_equals_the_numeric_law(build: str) -> None:
    """``SymbolicLaw.control`` (the closed form ``u* = C^-1 (-K phi - G)`` for display) evaluated at a
    state equals the compiled law there, for a velocity constraint with two components and distinct
    gains (the sled) and a holonomic one with both gain vectors (the circle)."""
    from vnhc_gym.systems import make_sled

    model = make_sled() if build == "sled" else circle()
    law = model.symbolic
    system = law.system
    gains = [2.0, 3.5][: model.m] if build == "sled" else [2.0, 3.5]
    rng = np.random.default_rng(1)
    state = rng.uniform(-1.0, 1.0, 2 * model.n)
    values = {**dict(zip(system.q, state[: model.n], strict=True)),
              **dict(zip(system.qd, state[model.n:], strict=True)), **system.params}
    closed = np.array(law.control(sp.Matrix(gains)).subs(values).evalf(), dtype=np.float64).reshape(-1)
    np.testing.assert_allclose(closed, model.control(state, gains=gains), rtol=1e-10, atol=1e-12)
