"""The cart-pole against facts derived by hand, independently of the module's sympy.

Hand derivation (``theta`` from the upright, positive towards ``+x``; the pole a uniform rod of
mass ``m``, centre of mass at ``l`` from the pivot, inertia ``m l^2 / 3`` about it; cart mass
``M``, friction ``b``, force ``u``).  Newton-Euler with ``(H, V)`` the force of the cart on the
rod at the pivot, the rod's centre at ``(x + l sin th, l cos th)``:

    cart:            M xdd = u - b xd - H
    rod, along x:    H = m d^2/dt^2 (x + l sin th) = m (xdd + l cos th thdd - l sin th thd^2)
    rod, along y:    V - m g = m d^2/dt^2 (l cos th) = -m l (sin th thdd + cos th thd^2)
    rod, turning:    (m l^2 / 3) thdd = l (V sin th - H cos th)

Eliminating ``H`` and ``V`` gives, with ``Mt = M + m`` and ``F = u - b xd``,

    temp = (F + m l thd^2 sin th) / Mt
    thdd = (g sin th - cos th temp) / (l (4/3 - m cos^2 th / Mt))
    xdd  = temp - m l cos th thdd / Mt

The constraint is ``phi = thd + lam sin th + mu xd + nu x``; its closed-loop and reduced-dynamics
facts are derived beside the tests that use them.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import expm

from vnhc_gym.mechanics import SingularControlError, simulate
from vnhc_gym.systems.cartpole import make_cartpole

# Parameter order of the model: (M_c, m_p, l, g, b_c, lam, mu, nu).
IM, IP, IL, IG, IB, ILAM, IMU, INU = range(8)


def episode_states(rng: np.random.Generator, b: int) -> np.ndarray:
    """Starts of the proposed task: x ~ U(-1, 1) m, theta ~ U(-0.3, 0.3) rad, xd ~ U(-0.5, 0.5) m/s,
    thetad ~ U(-0.5, 0.5) rad/s."""
    return np.column_stack([rng.uniform(-1, 1, b), rng.uniform(-0.3, 0.3, b), rng.uniform(-0.5, 0.5, b),
                            rng.uniform(-0.5, 0.5, b)])


def random_params(rng: np.random.Generator, b: int) -> np.ndarray:
    """Parameters away from the defaults, with ``mu`` inside ``(0, 1 / ell)`` (``ell = 4 l / 3``)."""
    length = rng.uniform(0.2, 1.5, b)
    return np.column_stack([rng.uniform(0.3, 5, b), rng.uniform(0.05, 2, b), length, rng.uniform(3, 20, b),
                            rng.uniform(0, 1, b), rng.uniform(0.5, 5, b), rng.uniform(0, 0.9, b) * 3 / (4 * length),
                            rng.uniform(0, 1, b)])


def newton_euler_acceleration(s: np.ndarray, u: np.ndarray, p: np.ndarray) -> np.ndarray:
    """``(xdd, thdd)`` from the eliminated Newton-Euler equations of the module docstring above."""
    th, xd, thd = s[:, 1], s[:, 2], s[:, 3]
    big, m, length, g, b = p[:, IM], p[:, IP], p[:, IL], p[:, IG], p[:, IB]
    total = big + m
    sn, cs = np.sin(th), np.cos(th)
    temp = (u - b * xd + m * length * thd**2 * sn) / total
    thdd = (g * sn - cs * temp) / (length * (4 / 3 - m * cs**2 / total))
    xdd = temp - m * length * cs * thdd / total
    return np.column_stack([xdd, thdd])


def hand_phi(s: np.ndarray, p: np.ndarray) -> np.ndarray:
    x, th, xd, thd = s.T
    return thd + p[:, ILAM] * np.sin(th) + p[:, IMU] * xd + p[:, INU] * x


def hand_energy(s: np.ndarray, p: np.ndarray) -> np.ndarray:
    """``T + V`` of the cart and the rod: the rod's centre moves at ``(xd + l cos th thd, -l sin th thd)``."""
    th, xd, thd = s[..., 1], s[..., 2], s[..., 3]
    big, m, length, g = p[IM], p[IP], p[IL], p[IG]
    centre_sq = (xd + length * np.cos(th) * thd) ** 2 + (length * np.sin(th) * thd) ** 2
    return big / 2 * xd**2 + m / 2 * centre_sq + m * length**2 / 6 * thd**2 + m * g * length * np.cos(th)


# --------------------------------------------------------------------------- 1. equations of motion


def test_cartpole_dynamics_match_newton_euler() -> None:
    model = make_cartpole()
    rng = np.random.default_rng(0)
    b = 40
    s = np.column_stack([rng.uniform(-3, 3, b), rng.uniform(-3, 3, b), rng.uniform(-3, 3, (b, 2))])
    p, u = random_params(rng, b), rng.uniform(-20, 20, b)
    want = newton_euler_acceleration(s, u, p)
    np.testing.assert_allclose(model.acceleration(s, u[:, None], p), want, rtol=1e-11, atol=1e-11)
    # The force enters linearly; the drift alone is the u = 0 case.
    a0, _ = model.dynamics(s, p)
    np.testing.assert_allclose(a0, newton_euler_acceleration(s, np.zeros(b), p), rtol=1e-11, atol=1e-11)
    np.testing.assert_allclose(model.phi(s, p)[:, 0], hand_phi(s, p), rtol=1e-13, atol=1e-13)


# --------------------------------------------------------------------------- 2. decoupling and singular set
#
# Y = M^-1 (1, 0) with M = [[Mt, m l c], [m l c, J]], J = 4/3 m l^2, det M = m l^2 (4/3 Mt - m c^2):
# Y = (J, -m l c) / det M, and d phi / d qd = (mu, 1), so
#     C = (mu J - m l c) / det M = (mu ell - cos th) / (l (4/3 Mt - m cos^2 th)),   ell = 4 l / 3.
# Sizes in the metric: |J_phi|^2 = (mu, 1) M^-1 (mu, 1)^T = (mu^2 J - 2 mu m l c + Mt) / det M,
# |Y|^2 = (1, 0) . Y = J / det M, so the measure is
#     |mu J - m l c| / sqrt(J (mu^2 J - 2 mu m l c + Mt)),
# which vanishes exactly where cos th = mu ell (at th = pi/2 when mu = 0).


def hand_decoupling(th: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    big, m, length, mu = p[:, IM], p[:, IP], p[:, IL], p[:, IMU]
    total, cs = big + m, np.cos(th)
    inertia = 4 / 3 * m * length**2
    c = (mu * 4 * length / 3 - cs) / (length * (4 / 3 * total - m * cs**2))
    measure = np.abs(mu * inertia - m * length * cs) / np.sqrt(inertia * (mu**2 * inertia - 2 * mu * m * length * cs
                                                                          + total))
    return c, measure


def test_cartpole_decoupling_is_the_hand_closed_form_and_the_law_gives_the_decay_rate() -> None:
    model = make_cartpole()
    rng = np.random.default_rng(1)
    b = 40
    s = np.column_stack([rng.uniform(-2, 2, b), rng.uniform(-1.0, 1.0, b), rng.uniform(-2, 2, (b, 2))])
    p = random_params(rng, b)
    c, _ = model.decoupling(s, p)
    want_c, want_measure = hand_decoupling(s[:, 1], p)
    np.testing.assert_allclose(c[:, 0, 0], want_c, rtol=1e-11)
    np.testing.assert_allclose(model.transversality(s, p), want_measure, rtol=1e-11)
    # The law's defining property, through the hand equations of motion: d phi/dt = -k phi.
    k = rng.uniform(0.5, 10, b)
    u = model.control(s, gains=k[:, None], params=p)[:, 0]
    x, th, xd, thd = s.T
    xdd, thdd = newton_euler_acceleration(s, u, p).T
    phi_dot = thdd + p[:, ILAM] * np.cos(th) * thd + p[:, IMU] * xdd + p[:, INU] * xd
    np.testing.assert_allclose(phi_dot, -k * hand_phi(s, p), rtol=1e-9, atol=1e-9)


def test_cartpole_transversality_vanishes_where_the_law_is_singular() -> None:
    model = make_cartpole()
    eps = np.array([0.3, 1e-1, 1e-2, 1e-3, 1e-5])
    # mu = 0: C is proportional to cos(theta), singular with the pole horizontal.  Near pi/2 the
    # measure is m l cos(th) / sqrt(J Mt) = sqrt(3 m / (4 Mt)) sin(eps).
    p0 = model.params(mu=0.0)
    for sign in (1.0, -1.0):
        s = np.column_stack([np.zeros(5), sign * (np.pi / 2 - eps), np.zeros(5), np.zeros(5)])
        measure = model.transversality(s, p0)
        np.testing.assert_allclose(measure, np.sqrt(3 * 0.2 / (4 * 1.2)) * np.sin(eps), rtol=1e-9)
        assert np.all(np.diff(measure) < 0)
    with pytest.raises(SingularControlError):
        model.control(np.array([0.0, np.pi / 2, 0.0, 0.0]), gains=5.0, params=p0)
    # Defaults (mu = 0.3, l = 0.5): the singular angle moves in to arccos(mu ell) = arccos(0.2).
    th_s = np.arccos(0.3 * 4 * 0.5 / 3)
    s = np.column_stack([np.zeros(5), th_s - eps, np.zeros(5), np.zeros(5)])
    measure = model.transversality(s)
    assert np.all(np.diff(measure) < 0) and measure[-1] < 1e-5
    assert model.transversality(np.array([0.0, th_s, 0.0, 0.0])) < 1e-14
    with pytest.raises(SingularControlError):
        model.control(np.array([0.0, -th_s, 0.1, 0.0]), gains=5.0)
    # Far from it at the task's termination angle 1.2 rad, and at the upright sqrt(...) of the hand form.
    assert model.transversality(np.array([0.0, 1.2, 0.0, 0.0])) > 0.05
    _, upright = hand_decoupling(np.zeros(1), model.params()[None])
    assert model.transversality(np.zeros(4)) == pytest.approx(upright[0], rel=1e-12)


# --------------------------------------------------------------------------- 3. energy and momentum


def test_cartpole_conserves_energy_and_momentum_without_force_or_friction() -> None:
    """With u = 0 and b = 0 the cart-pole is conservative, and x is cyclic: the horizontal momentum
    ``Mt xd + m l cos(th) thd`` is conserved too.  The pole falls over and swings (the run covers every
    angle), so RK4 at dt = 1 ms keeps both to ~1e-10 relative over 4 s."""
    model = make_cartpole()
    p = model.params(b_c=0.0, m_p=0.4, l=0.7, M_c=1.5)
    rng = np.random.default_rng(3)
    s0 = episode_states(rng, 8)
    np.testing.assert_allclose(model.energy(s0, p), hand_energy(s0, p), rtol=1e-13)
    tr = simulate(model, s0, 1e-3, 4000, feedback="open", params=p, record_every=50)
    assert not np.any(tr.flags)
    assert np.ptp(tr.states[:, :, 1], axis=0).min() > np.pi  # every pole fell past the horizontal
    energy = hand_energy(tr.states, p)
    scale = p[IP] * p[IG] * p[IL]  # m g l: the height of the potential
    assert np.max(np.abs(energy - energy[0])) < 1e-9 * scale
    th, xd, thd = tr.states[..., 1], tr.states[..., 2], tr.states[..., 3]
    momentum = (p[IM] + p[IP]) * xd + p[IP] * p[IL] * np.cos(th) * thd
    assert np.max(np.abs(momentum - momentum[0])) < 1e-9 * (p[IM] + p[IP])


def test_cartpole_friction_dissipates_at_the_rate_b_xd_squared() -> None:
    """With friction and u = 0, dE/dt = -b xd^2: the energy lost is the integral of b xd^2."""
    model = make_cartpole()
    p = model.params(b_c=0.8)
    s0 = episode_states(np.random.default_rng(4), 4)
    dt, n = 1e-3, 2000
    tr = simulate(model, s0, dt, n, feedback="open", params=p)
    energy = hand_energy(tr.states, p)
    power = p[IB] * tr.states[..., 2] ** 2
    lost = np.sum((power[1:] + power[:-1]) / 2, axis=0) * dt  # trapezoid: O(dt^2) error
    np.testing.assert_allclose(energy[0] - energy[-1], lost, rtol=1e-5)


# --------------------------------------------------------------------------- 4. the law's decay


@pytest.mark.parametrize("k", [1.0, 5.0])
def test_cartpole_phi_decays_exponentially(k: float) -> None:
    """Under continuous feedback d phi/dt = -k phi exactly, so phi(t) = exp(-k t) phi(0); the starts
    are the task's, and the pole stays far from the singular angle (|theta| < 0.45 along every run)."""
    model = make_cartpole()
    rng = np.random.default_rng(5)
    s0 = episode_states(rng, 24)
    s0 = s0[np.abs(model.phi(s0)[:, 0]) > 0.05]  # a relative check needs phi(0) clear of 0
    dt, n = 2e-3, 1000  # 2 s
    tr = simulate(model, s0, dt, n, feedback="continuous", gains=k, record_every=10)
    assert not np.any(tr.flags)
    assert np.max(np.abs(tr.states[:, :, 1])) < 0.45
    ratio = tr.phi[:, :, 0] / tr.phi[0, :, 0]
    expected = np.exp(-k * tr.t)[:, None]
    early = expected[:, 0] >= 1e-2
    # Relative while phi is large; below 1e-2 of phi(0) RK4's absolute O(dt^5) per step dominates.
    np.testing.assert_allclose(ratio[early], np.broadcast_to(expected, ratio.shape)[early], rtol=1e-6)
    assert np.max(np.abs(ratio - expected)) < 1e-8


# --------------------------------------------------------------------------- 5. reduced dynamics on phi = 0
#
# The rod's turning row, with V and H from its two translation rows, is free of the force:
#     cos th xdd + ell thdd = g sin th,   ell = 4 l / 3.
# On phi = 0, thd = -lam sin th - mu v - nu x (v = xd); differentiating,
# thdd = -lam cos th thd - mu vd - nu v, and putting that in gives
#     (cos th - mu ell) vd = g sin th + ell lam cos th thd + ell nu v.


def on_manifold(s: np.ndarray, p: np.ndarray) -> np.ndarray:
    out = s.copy()
    out[:, 3] = -p[ILAM] * np.sin(s[:, 1]) - p[IMU] * s[:, 2] - p[INU] * s[:, 0]
    return out


def reduced_rhs(z: np.ndarray, p: np.ndarray) -> np.ndarray:
    x, th, v = z.T
    lam, mu, nu, g, ell = p[ILAM], p[IMU], p[INU], p[IG], 4 * p[IL] / 3
    thd = -lam * np.sin(th) - mu * v - nu * x
    vd = (g * np.sin(th) + ell * lam * np.cos(th) * thd + ell * nu * v) / (np.cos(th) - mu * ell)
    return np.column_stack([v, thd, vd])


def rk4_reduced(z0: np.ndarray, p: np.ndarray, dt: float, n: int, every: int) -> np.ndarray:
    z, out = z0.copy(), [z0.copy()]
    for i in range(1, n + 1):
        k1 = reduced_rhs(z, p)
        k2 = reduced_rhs(z + dt / 2 * k1, p)
        k3 = reduced_rhs(z + dt / 2 * k2, p)
        k4 = reduced_rhs(z + dt * k3, p)
        z = z + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        if i % every == 0:
            out.append(z.copy())
    return np.array(out)


def test_cartpole_without_cart_terms_raises_the_pole_and_the_cart_runs_away() -> None:
    """mu = nu = 0: thd = -lam sin th gives tan(th/2) = tan(th0/2) exp(-lam t), and vd = g tan th
    + ell lam thd with d/dt artanh(sin th) = -lam tan th integrates to
    v = v0 + (g / lam)(artanh sin th0 - artanh sin th) - ell lam (th0 - th)."""
    model = make_cartpole()
    p = model.params(mu=0.0, nu=0.0, lam=1.5, l=0.6)
    lam, g, ell = p[ILAM], p[IG], 4 * p[IL] / 3
    s0 = on_manifold(episode_states(np.random.default_rng(6), 6), p)
    tr = simulate(model, s0, 2e-3, 4000, feedback="continuous", gains=5.0, params=p, record_every=25)
    assert not np.any(tr.flags)
    assert np.max(np.abs(tr.phi)) < 1e-11
    th0, v0 = s0[:, 1], s0[:, 2]
    theta = 2 * np.arctan(np.tan(th0 / 2) * np.exp(-lam * tr.t[:, None]))
    np.testing.assert_allclose(tr.states[:, :, 1], theta, rtol=0, atol=1e-11)
    speed = v0 + g / lam * (np.arctanh(np.sin(th0)) - np.arctanh(np.sin(theta))) - ell * lam * (th0 - theta)
    np.testing.assert_allclose(tr.states[:, :, 2], speed, rtol=0, atol=1e-10)
    # After 8 s the pole is up, and the cart keeps the limit speed: generically not 0.
    v_inf = v0 + g / lam * np.arctanh(np.sin(th0)) - ell * lam * th0
    np.testing.assert_allclose(tr.states[-1, :, 2], v_inf, atol=1e-4)
    assert np.min(np.abs(v_inf)) > 1e-2


def test_cartpole_reduced_dynamics_bring_pole_up_and_cart_home() -> None:
    """Defaults (lam, mu, nu) = (2, 0.3, 0.2): the closed loop started on phi = 0 follows the hand
    reduced ODE, and pole, cart speed and cart position all go to 0."""
    model = make_cartpole()
    p = model.params()
    s0 = on_manifold(episode_states(np.random.default_rng(7), 6), p)
    dt, every = 2e-3, 50
    tr = simulate(model, s0, dt, 5000, feedback="continuous", gains=5.0, record_every=every)  # 10 s
    assert not np.any(tr.flags)
    z = rk4_reduced(s0[:, :3], p, dt, 5000, every)
    np.testing.assert_allclose(tr.states[:, :, :3], z, rtol=0, atol=1e-10)
    np.testing.assert_allclose(tr.states[:, :, 3], -p[ILAM] * np.sin(z[..., 1]) - p[IMU] * z[..., 2]
                               - p[INU] * z[..., 0], rtol=0, atol=1e-8)
    # 30 s: the slowest root is -0.64 (1/s), so everything has decayed by ~exp(-19).
    late = simulate(model, s0, 0.01, 3000, feedback="continuous", gains=5.0, record_every=3000)
    assert np.max(np.abs(late.states[-1])) < 1e-6 * np.max(np.abs(s0))


def test_cartpole_reduced_dynamics_linearise_to_the_hand_polynomial() -> None:
    """Near the upright, (x, th, v) follows z' = A z with (from the reduced ODE, D = 1 - mu ell)
        A = [[0, 0, 1], [-nu, -lam, -mu], [-ell lam nu, g - ell lam^2, ell (nu - lam mu)] / D],
    whose characteristic polynomial is s^3 + (lam - ell nu)/D s^2 + mu g/D s + nu g/D: the closed
    loop from a start 1e-4 off the upright matches expm(A t) z0 to second order, and the roots are
    the ones the module docstring states."""
    model = make_cartpole()
    p = model.params()
    lam, mu, nu, g, ell = p[ILAM], p[IMU], p[INU], p[IG], 4 * p[IL] / 3
    d = 1 - mu * ell
    a = np.array([[0, 0, 1], [-nu, -lam, -mu],
                  [-ell * lam * nu / d, (g - ell * lam**2) / d, ell * (nu - lam * mu) / d]])
    poly = np.array([1, (lam - ell * nu) / d, mu * g / d, nu * g / d])
    np.testing.assert_allclose(np.sort_complex(np.linalg.eigvals(a)), np.sort_complex(np.roots(poly)), rtol=1e-10)
    roots = np.sort_complex(np.roots(poly))
    np.testing.assert_allclose(roots, [-1.0517, -0.6408 - 1.3864j, -0.6408 + 1.3864j], atol=1e-3)
    amp = 1e-4
    z0 = amp * np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.6, -0.8, 0.3]])
    s0 = on_manifold(np.column_stack([z0, np.zeros(4)]), p)
    tr = simulate(model, s0, 0.01, 800, feedback="continuous", gains=5.0, record_every=20)  # 8 s
    lin = np.stack([z0 @ expm(a * t).T for t in tr.t])
    np.testing.assert_allclose(tr.states[:, :, :3], lin, rtol=0, atol=1e-3 * amp)
