"""Acceptance tests of the paper's two systems (flocking, USV in a current), and of the sled.

The expected values are hand-derived closed forms (written out here, in numpy, independently of
the library), the paper's printed invariance controls, and the exact closed-loop solution
``phi(t) = exp(-K t) phi(0)`` of Theorem 2.  The paper's printed USV law (an erratum) is in
``test_paper.py``.
"""

from __future__ import annotations

import inspect
import re

import numpy as np
import pytest

from vnhc_gym.mechanics import ConstrainedSystem, simulate
from vnhc_gym.systems import (
    CURRENTS,
    FLOCKING_PRESETS,
    USV_PRESETS,
    make_flocking,
    make_sled,
    make_usv,
    random_field_params,
)
from vnhc_gym.systems.currents import RANDOM_PARAM_NAMES, RANDOM_WEIGHTS

CURRENT_NAMES = ("northeast", "anticyclone", "vortex", "shear", "random")
DT = 0.01
N_STEPS = 500  # t <= 5 s
RTOL_DECAY = 1e-5


# --------------------------------------------------------------------------- independent formulas


def flocking_closed_form(s: np.ndarray, params: np.ndarray, gains: np.ndarray, n_agents: int):
    """The paper's Section IV-A, derived by hand: (phi, C, G, u*).

    phi^b = xd_N zd_b - xd_b zd_N depends on velocities only; Y^b = (dx_b + dz_b)/m_b gives
    C = diag((xd_N - zd_N)/m_b); the drift (0, -g) on every z gives G^b = g (xd_b - xd_N).
    """
    n = n_agents
    xd, zd = s[:, 2 * n:3 * n], s[:, 3 * n:4 * n]
    masses, g = params[:, :n], params[:, n:n + 1]
    xd4, zd4 = xd[:, -1:], zd[:, -1:]
    xdb, zdb, mb = xd[:, :-1], zd[:, :-1], masses[:, :-1]
    phi = xd4 * zdb - xdb * zd4
    c_diag = (xd4 - zd4) / mb
    g_vec = g * (xdb - xd4)
    u_star = mb * (g * (xd4 - xdb) - gains * phi) / (xd4 - zd4)
    return phi, c_diag, g_vec, u_star


def current_numpy(name: str, x: np.ndarray, y: np.ndarray, p: dict[str, float]) -> tuple[np.ndarray, np.ndarray]:
    """The current fields of the library's table, re-typed in numpy (unscaled)."""
    if name == "northeast":
        return p["c_c1"] + 0 * x, p["c_c2"] + 0 * x
    if name == "anticyclone":
        return p["c_a"] * y, p["c_a"] * (-x + y)
    if name == "vortex":
        dx, dy = x - p["c_x0"], y - p["c_y0"]
        w = p["c_gamma"] / (2 * np.pi) / (dx**2 + dy**2 + p["c_rc"] ** 2)
        return -w * dy, w * dx
    if name == "shear":
        return p["c_u0"] + p["c_s"] * y, 0 * x
    if name == "random":  # C = (d psi/dy, -d psi/dx), psi = sum A cos(k0 (i x + j y)) + B sin(k0 (i x + j y))
        c1, c2 = 0 * x, 0 * x
        for (i, j), a, b in random_modes_numpy(p):
            arg = RANDOM_K0_M * (i * x + j * y)
            dpsi = RANDOM_K0_M * (-a * np.sin(arg) + b * np.cos(arg))  # d psi_mode / d(k0 (i x + j y)) * k0
            c1, c2 = c1 + j * dpsi, c2 - i * dpsi
        return c1, c2
    raise KeyError(name)


RANDOM_PERIOD_M = 16.0
RANDOM_K0_M = 2 * np.pi / RANDOM_PERIOD_M


def random_modes_numpy(p: dict[str, float]) -> list[tuple[tuple[int, int], float, float]]:
    """The 14 lattice modes (i, j) of the random field, i > 0 or (i = 0, j > 0), 1 <= i^2 + j^2 <= 9,
    with their amplitudes (A, B) = (c_a_<i>_<j>, c_b_<i>_<j>), 'm' for a minus sign."""
    out = []
    for i in range(4):
        for j in range(-3, 4):
            if (i > 0 or j > 0) and 1 <= i * i + j * j <= 9:
                label = f"{i}_{j}" if j >= 0 else f"{i}_m{-j}"
                out.append(((i, j), p[f"c_a_{label}"], p[f"c_b_{label}"]))
    assert len(out) == 14
    return out


def random_jacobian_numpy(x: np.ndarray, y: np.ndarray, p: dict[str, float]) -> np.ndarray:
    """dC/d(x, y) of the random field by hand: per mode n = (i, j), d2 psi/dx_p dx_q = -k0^2 n_p n_q (A cos + B sin)."""
    jac = np.zeros((*np.shape(x), 2, 2))
    for (i, j), a, b in random_modes_numpy(p):
        arg = RANDOM_K0_M * (i * x + j * y)
        w = -RANDOM_K0_M**2 * (a * np.cos(arg) + b * np.sin(arg))
        jac[..., 0, 0] += j * i * w  # d/dx dpsi/dy
        jac[..., 0, 1] += j * j * w
        jac[..., 1, 0] -= i * i * w
        jac[..., 1, 1] -= i * j * w
    return jac


def usv_closed_form(s: np.ndarray, p: dict[str, float], name: str, k: float):
    """The paper's Section IV-B, derived by hand: (phi, C, G, u*).

    phi = mu(qd - C) with mu = (sin, -cos, 0); C = mu . Y = (sin^2 + cos^2)/m = 1/m; in G the
    current terms cancel, leaving G = thetad (xd cos + yd sin).
    """
    x, y, th, xd, yd, thd = s.T
    c1, c2 = current_numpy(name, x, y, p)
    c1, c2 = p["current_scale"] * c1, p["current_scale"] * c2
    sn, cs = np.sin(th), np.cos(th)
    phi = sn * xd - cs * yd + cs * c2 - sn * c1
    forward = xd * cs + yd * sn
    return phi, 1.0 / p["m"], thd * forward, -p["m"] * (k * phi + thd * forward)


def usv_w_by_hand(name: str, s: np.ndarray, p: dict[str, float]) -> tuple[np.ndarray, np.ndarray]:
    """W = m dV/dt with V1 = s^2 C1 - s c C2, V2 = -s c C1 + c^2 C2; Jacobian by central differences."""
    x, y, th, xd, yd, thd = s.T
    scale = p["current_scale"]

    def cur(xx, yy):
        a, b = current_numpy(name, xx, yy, p)
        return scale * a, scale * b

    h = 1e-6
    c1, c2 = cur(x, y)
    c1x, c2x = [(a - b) / (2 * h) for a, b in zip(cur(x + h, y), cur(x - h, y), strict=True)]
    c1y, c2y = [(a - b) / (2 * h) for a, b in zip(cur(x, y + h), cur(x, y - h), strict=True)]
    sn, cs = np.sin(th), np.cos(th)
    c1d, c2d = c1x * xd + c1y * yd, c2x * xd + c2y * yd
    v1d = (2 * sn * cs * c1 - (cs**2 - sn**2) * c2) * thd + sn**2 * c1d - sn * cs * c2d
    v2d = (-(cs**2 - sn**2) * c1 - 2 * sn * cs * c2) * thd - sn * cs * c1d + cs**2 * c2d
    return p["m"] * v1d, p["m"] * v2d


def usv_param_dict(model: ConstrainedSystem, vec: np.ndarray) -> dict[str, float]:
    return dict(zip(model.param_names, map(float, vec), strict=True))


# --------------------------------------------------------------------------- random states


def random_flocking_states(rng: np.random.Generator, n_agents: int, batch: int) -> np.ndarray:
    """Off-manifold states, |phi^b(0)| >= 0.2, with xd_N - zd_N in [0.5, 3].

    xd_N - zd_N only grows as the leader falls, so C = diag((xd_N - zd_N)/m_b) stays regular.
    """
    n = n_agents
    s = np.empty((batch, 4 * n))
    s[:, :2 * n] = rng.uniform(-50, 50, (batch, 2 * n))
    s[:, 2 * n:] = rng.uniform(-2, 2, (batch, 2 * n))
    s[:, 4 * n - 1] = s[:, 3 * n - 1] - rng.uniform(0.5, 3, batch)
    for _ in range(100):  # redraw followers whose phi^b = xd_N zd_b - xd_b zd_N is too small
        phi = s[:, 3 * n - 1:3 * n] * s[:, 3 * n:4 * n - 1] - s[:, 2 * n:3 * n - 1] * s[:, 4 * n - 1:]
        rows, cols = np.nonzero(np.abs(phi) < 0.2)
        if rows.size == 0:
            return s
        s[rows, 2 * n + cols] = rng.uniform(-2, 2, rows.size)
        s[rows, 3 * n + cols] = rng.uniform(-2, 2, rows.size)
    raise AssertionError("could not draw off-manifold states")


def random_usv_states(rng: np.random.Generator, name: str, batch: int, params: dict[str, float] | None = None,
                      phi0: np.ndarray | None = None) -> np.ndarray:
    """States with a forward speed through the water in [0.5, 2] and phi = phi0 (default +-[0.2, 1]).

    With the boat moving forward the zero dynamics ``I thetadd = -m thetad (xd cos + yd sin)``
    are damped, so the closed loop stays bounded over the test horizon.
    """
    scale = 1.0 if params is None else params["current_scale"]
    p = dict(CURRENTS[name].defaults) if params is None else {k[2:]: v for k, v in params.items() if k.startswith("c_")}
    x, y = rng.uniform(-2, 2, (2, batch))
    th = rng.uniform(-np.pi, np.pi, batch)
    cur = scale * CURRENTS[name].value(x, y, p)
    heading = np.column_stack([np.cos(th), np.sin(th)])
    normal = np.column_stack([np.sin(th), -np.cos(th)])
    forward = rng.uniform(0.5, 2, batch)
    if phi0 is None:
        phi0 = rng.choice([-1.0, 1.0], batch) * rng.uniform(0.2, 1.0, batch)
    # Velocity = current + forward speed along the heading (+ phi0 sideways): phi = mu(qd - C) = phi0.
    vel = cur + (forward - np.sum(cur * heading, axis=1))[:, None] * heading + phi0[:, None] * normal
    return np.column_stack([x, y, th, vel, rng.uniform(-0.5, 0.5, batch)])


# --------------------------------------------------------------------------- exponential decay (Theorem 2)


def assert_exponential_decay(t: np.ndarray, phi: np.ndarray, gains: np.ndarray) -> None:
    """phi(t)/phi(0) == exp(-k t) per component, to RTOL_DECAY relative (plus a 1e-7 absolute floor).

    The floor: RK4 adds a truncation error of O(dt^5) per step that does not shrink with phi, so
    once phi has decayed by 1e-2 or more it dominates; the relative criterion holds while
    exp(-k t) >= 1e-2, and afterwards the error stays below RTOL_DECAY * 1e-2 = 1e-7 of phi(0).
    """
    ratio = phi / phi[0]
    expected = np.broadcast_to(np.exp(-t[:, None, None] * gains[None, None, :]), ratio.shape)
    err = np.abs(ratio - expected)
    worst = np.max(err / (expected + 1e-2))
    assert worst < RTOL_DECAY, f"phi/phi0 deviates from exp(-k t) by {worst:.2e} (relative)"
    early = expected >= 0.1
    assert np.max(err[early] / expected[early]) < RTOL_DECAY  # strictly relative over the first decade
    assert np.all(np.abs(phi[-1]) < np.abs(phi[0]))


@pytest.mark.parametrize("k", [0.5, 1.0, 3.0])
def test_flocking_phi_decays_exponentially(k: float) -> None:
    model = make_flocking(4)
    rng = np.random.default_rng(100)
    s0 = random_flocking_states(rng, 4, 20)
    assert np.all(np.abs(model.phi(s0)) >= 0.2)
    tr = simulate(model, s0, DT, N_STEPS, feedback="continuous", gains=k, record_every=5)
    assert not np.any(tr.flags)
    assert tr.t[-1] == pytest.approx(5.0)
    assert_exponential_decay(tr.t, tr.phi, np.full(3, k))


@pytest.mark.parametrize("n_agents, gains", [(4, (0.5, 1.0, 3.0)), (3, (2.0, 0.3)), (6, (0.5, 1.0, 3.0, 0.2, 1.5))])
def test_flocking_phi_decays_per_component(n_agents: int, gains: tuple[float, ...]) -> None:
    model = make_flocking(n_agents)
    rng = np.random.default_rng(101 + n_agents)
    s0 = random_flocking_states(rng, n_agents, 20)
    params = np.concatenate([rng.uniform(0.5, 4, (20, n_agents)), rng.uniform(5, 15, (20, 1))], axis=1)
    tr = simulate(model, s0, DT, N_STEPS, feedback="continuous", gains=gains, params=params, record_every=5)
    assert not np.any(tr.flags)
    assert_exponential_decay(tr.t, tr.phi, np.asarray(gains))


@pytest.mark.parametrize("name", CURRENT_NAMES)
@pytest.mark.parametrize("k", [0.5, 1.0, 3.0])
def test_usv_phi_decays_exponentially(name: str, k: float) -> None:
    model = make_usv(name)
    rng = np.random.default_rng(200 + CURRENT_NAMES.index(name))
    s0 = random_usv_states(rng, name, 20)
    tr = simulate(model, s0, DT, N_STEPS, feedback="continuous", gains=k, record_every=5)
    assert not np.any(tr.flags)
    assert_exponential_decay(tr.t, tr.phi, np.array([k]))


def test_usv_decay_with_perturbed_parameters() -> None:
    model = make_usv("vortex")
    rng = np.random.default_rng(7)
    p = usv_param_dict(model, model.params(m=4.0, I=0.7, current_scale=1.6, c_x0=0.4, c_rc=0.8))
    s0 = random_usv_states(rng, "vortex", 20, params=p)
    tr = simulate(model, s0, DT, N_STEPS, gains=2.0, params=np.array(list(p.values())))
    assert_exponential_decay(tr.t, tr.phi, np.array([2.0]))


def test_sampled_feedback_is_not_exact() -> None:
    # With the law held over each step (zero-order hold), phi no longer follows exp(-k t) exactly.
    model = make_flocking(4)
    preset = FLOCKING_PRESETS["paper"]
    tr_c = simulate(model, preset.state(), 0.1, 300, feedback="continuous", params=preset.params())
    tr_s = simulate(model, preset.state(), 0.1, 300, feedback="sampled", params=preset.params())
    assert np.max(np.abs(tr_c.phi[-1])) < 1e-7  # exp(-30) |phi0| plus the RK4 floor
    assert np.max(np.abs(tr_s.phi[-1])) > 1e-5  # levels off at the sampled-data floor (near 1e-4)


# --------------------------------------------------------------------------- closed forms at random states


@pytest.mark.parametrize("n_agents", [3, 4, 6])
def test_flocking_matches_closed_form(n_agents: int) -> None:
    model = make_flocking(n_agents)
    assert model.n == 2 * n_agents and model.m == n_agents - 1
    assert model.param_names == (*[f"m_{i}" for i in range(1, n_agents + 1)], "g")
    rng = np.random.default_rng(300 + n_agents)
    b = 50
    s = rng.uniform(-20, 20, (b, 4 * n_agents))
    params = np.concatenate([rng.uniform(0.3, 5, (b, n_agents)), rng.uniform(1, 20, (b, 1))], axis=1)
    gains = rng.uniform(0, 4, (b, n_agents - 1))
    phi, c_diag, g_vec, u_star = flocking_closed_form(s, params, gains, n_agents)
    np.testing.assert_allclose(model.phi(s, params), phi, rtol=1e-10, atol=1e-12)
    c, g = model.decoupling(s, params)
    expected_c = np.zeros((b, n_agents - 1, n_agents - 1))
    idx = np.arange(n_agents - 1)
    expected_c[:, idx, idx] = c_diag
    np.testing.assert_allclose(c, expected_c, rtol=1e-10, atol=1e-14)
    np.testing.assert_allclose(g, g_vec, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(model.control(s, gains=gains, params=params), u_star, rtol=1e-10)
    # Dynamics (paper's Euler-Lagrange equations): m_b xdd_b = u_b, m_b zdd_b = u_b - m_b g, leader free.
    a0, y = model.dynamics(s, params)
    np.testing.assert_allclose(a0, np.concatenate([np.zeros((b, n_agents)), -np.repeat(params[:, -1:], n_agents, 1)],
                                                  axis=1), atol=1e-15)
    expected_y = np.zeros((b, 2 * n_agents, n_agents - 1))
    expected_y[:, idx, idx] = 1 / params[:, :-2]
    expected_y[:, n_agents + idx, idx] = 1 / params[:, :-2]
    np.testing.assert_allclose(y, expected_y, rtol=1e-14)
    # Energy: sum m_i (xd_i^2 + zd_i^2)/2 + m_i g z_i.
    m_i = params[:, :n_agents]
    xd, zd, z = s[:, 2 * n_agents:3 * n_agents], s[:, 3 * n_agents:], s[:, n_agents:2 * n_agents]
    energy = np.sum(m_i * (xd**2 + zd**2) / 2 + m_i * params[:, -1:] * z, axis=1)
    np.testing.assert_allclose(model.energy(s, params), energy, rtol=1e-10)


def test_flocking_printed_law_with_identity_gain() -> None:
    # The paper's final u* (K = I), typed from Section IV-A with the default m_i = 2, g = 10.
    model = make_flocking(4)
    rng = np.random.default_rng(11)
    s = rng.uniform(-5, 5, (10, 16))
    xd, zd = s[:, 8:12], s[:, 12:16]
    printed = 2.0 / (xd[:, 3:] - zd[:, 3:]) * (10.0 * (xd[:, 3:] - xd[:, :3]) - (xd[:, 3:] * zd[:, :3]
                                                                                 - xd[:, :3] * zd[:, 3:]))
    np.testing.assert_allclose(model.control(s, gains=1.0), printed, rtol=1e-10)


@pytest.mark.parametrize("name", CURRENT_NAMES)
def test_usv_matches_closed_form(name: str) -> None:
    model = make_usv(name)
    rng = np.random.default_rng(400 + CURRENT_NAMES.index(name))
    b = 40
    for scale_case in range(2):
        # Case 0: defaults; case 1: current_scale != 1, non-default masses, perturbed field parameters.
        vec = model.default_params.copy()
        if scale_case:
            vec[0], vec[1], vec[2] = rng.uniform(1, 30), rng.uniform(0.5, 5), rng.uniform(0.3, 2.5)
            vec[3:] *= 1 + 0.3 * rng.uniform(-1, 1, vec.size - 3)
        p = usv_param_dict(model, vec)
        assert model.param_names[:3] == ("m", "I", "current_scale")
        s = np.column_stack([rng.uniform(-4, 4, (b, 2)), rng.uniform(-np.pi, np.pi, b), rng.uniform(-3, 3, (b, 3))])
        k = rng.uniform(0, 4, b)
        phi, c_val, g_val, u_star = usv_closed_form(s, p, name, k)
        np.testing.assert_allclose(model.phi(s, vec)[:, 0], phi, rtol=1e-10, atol=1e-12)
        c, g = model.decoupling(s, vec)
        np.testing.assert_allclose(c[:, 0, 0], c_val, rtol=1e-10)
        np.testing.assert_allclose(g[:, 0], g_val, rtol=1e-10, atol=1e-11)
        np.testing.assert_allclose(model.control(s, gains=k[:, None], params=vec)[:, 0], u_star, rtol=1e-10,
                                   atol=1e-10 * p["m"])
        # The dynamics: m xdd = u sin + W1, m ydd = -u cos + W2, I thdd = u (W by hand, finite differences).
        u = rng.uniform(-2, 2, b)
        w1, w2 = usv_w_by_hand(name, s, p)
        acc = model.acceleration(s, u[:, None], vec)
        th = s[:, 2]
        expected = np.column_stack([(u * np.sin(th) + w1) / p["m"], (-u * np.cos(th) + w2) / p["m"], u / p["I"]])
        np.testing.assert_allclose(acc, expected, rtol=1e-6, atol=1e-7)
        # The compiled current outputs equal the numpy field.
        c1, c2 = current_numpy(name, s[:, 0], s[:, 1], p)
        out = model.outputs(s, vec)
        np.testing.assert_allclose(out[:, :2], p["current_scale"] * np.column_stack([c1, c2]), rtol=1e-10,
                                   atol=1e-12)
        # Kinetic energy only.
        energy = 0.5 * p["m"] * (s[:, 3] ** 2 + s[:, 4] ** 2) + 0.5 * p["I"] * s[:, 5] ** 2
        np.testing.assert_allclose(model.energy(s, vec), energy, rtol=1e-12)


# --------------------------------------------------------------------------- on the manifold: u* == u_hat


@pytest.mark.parametrize("n_agents", [3, 4, 6])
def test_flocking_on_manifold(n_agents: int) -> None:
    model = make_flocking(n_agents)
    rng = np.random.default_rng(500 + n_agents)
    b, n = 30, n_agents
    s = np.empty((b, 4 * n))
    s[:, :2 * n] = rng.uniform(-50, 50, (b, 2 * n))
    xd4 = rng.uniform(-3, 3, b)
    zd4 = xd4 - rng.choice([-1, 1], b) * rng.uniform(0.5, 3, b)
    lam = rng.uniform(-2, 2, (b, n - 1))  # parallel and anti-parallel followers
    s[:, 2 * n:3 * n] = np.column_stack([lam * xd4[:, None], xd4])
    s[:, 3 * n:] = np.column_stack([lam * zd4[:, None], zd4])
    params = np.concatenate([rng.uniform(0.5, 4, (b, n)), rng.uniform(5, 15, (b, 1))], axis=1)
    assert np.max(np.abs(model.phi(s, params))) < 1e-13
    u_hat = model.invariance_control(s, params)
    # The paper's printed u_hat = g diag(m_b) (xd_4 - xd_b) / (xd_4 - zd_4).
    g, mb = params[:, -1:], params[:, :n - 1]
    printed = g * mb * (xd4[:, None] - s[:, 2 * n:3 * n - 1]) / (xd4 - zd4)[:, None]
    np.testing.assert_allclose(u_hat, printed, rtol=1e-12)
    for gains in (0.5, 3.0, rng.uniform(0, 5, (b, n - 1))):
        np.testing.assert_allclose(model.control(s, gains=gains, params=params), u_hat, rtol=1e-9, atol=1e-12)
    # Off the manifold the two differ (so the comparison above can fail).
    s_off = s.copy()
    s_off[:, 2 * n] += 0.5
    assert np.all(np.abs(model.control(s_off, gains=1.0, params=params) - model.invariance_control(s_off, params))[:, 0]
                  > 1e-3)


@pytest.mark.parametrize("name", CURRENT_NAMES)
def test_usv_on_manifold(name: str) -> None:
    model = make_usv(name)
    rng = np.random.default_rng(600 + CURRENT_NAMES.index(name))
    b = 30
    vec = model.params(m=7.0, I=2.2, current_scale=1.3)
    x, y = rng.uniform(-4, 4, (2, b))
    th = rng.uniform(-np.pi, np.pi, b)
    c1, c2 = 1.3 * CURRENTS[name].value(x, y).T
    v = rng.uniform(-2, 2, b)
    # First rows: ground speed along the heading xd cos + yd sin in [0.5, 2] (for the invariance run below).
    v[:15] = rng.uniform(0.5, 2, 15) - (c1 * np.cos(th) + c2 * np.sin(th))[:15]
    # Velocity relative to the water along the heading: qd - C = v (cos, sin), so phi = 0.
    xd, yd = c1 + v * np.cos(th), c2 + v * np.sin(th)
    thd = rng.uniform(-2, 2, b)
    thd[:15] = rng.uniform(-0.5, 0.5, 15)
    s = np.column_stack([x, y, th, xd, yd, thd])
    assert np.max(np.abs(model.phi(s, vec))) < 1e-12
    u_hat = model.invariance_control(s, vec)[:, 0]
    # The paper's printed u_hat = -m thetad (xd cos theta + yd sin theta).
    np.testing.assert_allclose(u_hat, -7.0 * thd * (xd * np.cos(th) + yd * np.sin(th)), rtol=1e-10, atol=1e-12)
    for k in (0.5, 1.0, 3.0):
        np.testing.assert_allclose(model.control(s, gains=k, params=vec)[:, 0], u_hat, rtol=1e-9, atol=1e-10)
    # The manifold is invariant under u_hat (K = 0): phi stays 0.  Only rows moving forward: backwards,
    # the zero dynamics I thetadd = -m thetad (xd cos + yd sin) are unstable.
    tr = simulate(model, s[:15], DT, 100, feedback="continuous", gains=0.0, params=vec)
    assert not np.any(tr.flags)
    assert np.max(np.abs(tr.phi)) < 1e-7  # only the RK4 truncation error: O(dt^5) per step


# --------------------------------------------------------------------------- the paper's numbers


def test_presets_match_the_paper() -> None:
    flock = FLOCKING_PRESETS["paper"]
    s = flock.state()
    assert flock.dt == 0.01 and flock.duration == 500.0
    np.testing.assert_array_equal(s[:4], [10, 30, 50, 10])
    np.testing.assert_array_equal(s[4:8], [56, 100, 100, 90])
    np.testing.assert_array_equal(s[8:12], [0.5, 1, -1, 0.6])
    np.testing.assert_array_equal(s[12:], [1, 1, -1, 0])
    np.testing.assert_array_equal(flock.params(), [2, 2, 2, 2, 10])
    ne, ac = USV_PRESETS["paper-northeast"], USV_PRESETS["paper-anticyclone"]
    np.testing.assert_allclose(ne.state(), [1, 1, np.pi / 2, 0.8, 0.5, 0])
    np.testing.assert_allclose(ac.state(), [1, 1, np.pi / 2, 1, 1, 0])
    assert (ne.m, ne.inertia, ac.m, ac.inertia) == (10.0, 1.5, 20.0, 4.0)
    # The anticyclone start is on the manifold: theta = pi/2, so phi = xd - C1 = 1 - a y = 1 - 1 = 0.
    assert abs(make_usv("anticyclone").phi(ac.state(), ac.params())[0]) < 1e-15
    assert make_usv("northeast").phi(ne.state(), ne.params())[0] == pytest.approx(0.8 - 1.0)


def test_unknown_current_is_rejected() -> None:
    with pytest.raises(ValueError, match="current"):
        make_usv("hurricane")
    with pytest.raises(ValueError, match="n_agents"):
        make_flocking(1)


# --------------------------------------------------------------------------- the random current field


def _prefixed(p: dict[str, float]) -> dict[str, float]:
    return {f"c_{k}": v for k, v in p.items()}


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_random_field_matches_the_formula(seed: int) -> None:
    """value / jacobian == the lattice sum differentiated by hand, far from the origin too."""
    field = CURRENTS["random"]
    p = random_field_params(seed)
    x, y = np.random.default_rng(700 + seed).uniform(-40, 40, (2, 300))
    c1, c2 = current_numpy("random", x, y, _prefixed(p))
    np.testing.assert_allclose(field.value(x, y, p), np.stack([c1, c2], axis=-1), rtol=0, atol=1e-12)
    np.testing.assert_allclose(field.jacobian(x, y, p), random_jacobian_numpy(x, y, _prefixed(p)), rtol=0,
                               atol=1e-12)


@pytest.mark.parametrize("seed", [0, 5, 17, 123])
def test_random_field_is_divergence_free_and_periodic(seed: int) -> None:
    field = CURRENTS["random"]
    p = random_field_params(seed)
    x, y = np.random.default_rng(800 + seed).uniform(-30, 30, (2, 300))
    jac = field.jacobian(x, y, p)
    assert np.max(np.abs(jac[..., 0, 0] + jac[..., 1, 1])) < 1e-12
    assert np.max(np.abs(jac)) > 0.1  # not trivially zero
    v = field.value(x, y, p)
    for dx, dy in ((RANDOM_PERIOD_M, 0.0), (0.0, RANDOM_PERIOD_M), (-2 * RANDOM_PERIOD_M, RANDOM_PERIOD_M)):
        np.testing.assert_allclose(field.value(x + dx, y + dy, p), v, rtol=0, atol=1e-11)
    # ... and not periodic with half the period
    assert np.max(np.abs(field.value(x + RANDOM_PERIOD_M / 2, y, p) - v)) > 0.1


@pytest.mark.parametrize("speed", [1.0, 2.5])
def test_random_field_mean_square_speed(speed: float) -> None:
    """E|C|^2 = speed^2, split evenly between the components (isotropic second moments)."""
    field = CURRENTS["random"]
    rng = np.random.default_rng(900)
    c = np.concatenate([field.value(*rng.uniform(-50, 50, (2, 50)), random_field_params(rng, speed=speed))
                        for _ in range(400)])
    ms = np.mean(c**2, axis=0)
    assert ms.sum() == pytest.approx(speed**2, rel=0.1)
    np.testing.assert_allclose(ms, speed**2 / 2, rtol=0.15)


def test_random_field_parameters_contract() -> None:
    """Amplitudes are z * RANDOM_WEIGHTS with z standard normal in RANDOM_PARAM_NAMES order (the env relies on it)."""
    field = CURRENTS["random"]
    assert tuple(field.defaults) == RANDOM_PARAM_NAMES
    assert field.defaults == random_field_params(0)
    assert all(name.isidentifier() for name in RANDOM_PARAM_NAMES) and "a_1_m2" in RANDOM_PARAM_NAMES
    assert RANDOM_WEIGHTS.shape == (len(RANDOM_PARAM_NAMES),) == (28,)
    z = np.random.default_rng(42).standard_normal(len(RANDOM_PARAM_NAMES))
    np.testing.assert_array_equal(list(random_field_params(np.random.default_rng(42)).values()), z * RANDOM_WEIGHTS)
    np.testing.assert_array_equal(list(random_field_params(42).values()), z * RANDOM_WEIGHTS)
    # E|C|^2 = sum_modes w^2 k0^2 |n|^2 = 1, and the spectrum peaks at wavelength 8 m (|n| = 2)
    modes = [m for m, _, _ in random_modes_numpy({f"c_{k}": 0.0 for k in RANDOM_PARAM_NAMES})]
    assert RANDOM_PARAM_NAMES == tuple(f"{ab}_{i}_{j}".replace("-", "m") for i, j in modes for ab in "ab")
    n2 = np.array([i * i + j * j for i, j in modes])
    energy = RANDOM_WEIGHTS[::2] ** 2 * RANDOM_K0_M**2 * n2
    assert energy.sum() == pytest.approx(1.0, rel=1e-12)
    assert n2[np.argmax(energy)] == 4
    np.testing.assert_array_equal(RANDOM_WEIGHTS[::2], RANDOM_WEIGHTS[1::2])  # A and B alike: stationary


def test_random_current_printed_drift_has_only_four_field_trig_calls() -> None:
    """The lattice field needs sin/cos(k0 x) and sin/cos(k0 y) only (plus the heading's sin/cos):
    products of those give every mode, so the printed drift has at most 6 sine/cosine calls."""
    src = inspect.getsource(make_usv("random").functions.drift)
    calls = re.findall(r"\bjnp\.(?:sin|cos)\(([^()]*(?:\([^()]*\))?[^()]*)\)", src)
    assert 0 < len(calls) <= 6, calls


# ---------------------------------------------------------------------- the sled
# The sled (knife-edge blade, offset centre of mass) against its hand-derived Euler-Lagrange
# equations, its constraint and energy typed by hand, and the law's exponential decay.
#
# Hand derivation, from ``T = m/2 [(xd - a sin(th) thd)^2 + (yd + a cos(th) thd)^2] + I/2 thd^2``
# and the forces ``u_1 (cos th, sin th, 0) + u_2 (0, 0, 1)``:
#
#     m xdd - m a sin(th) thdd - m a cos(th) thd^2 = cos(th) u_1
#     m ydd + m a cos(th) thdd - m a sin(th) thd^2 = sin(th) u_1
#     -m a sin(th) xdd + m a cos(th) ydd + (I + m a^2) thdd = u_2
#
# (the theta equation's velocity terms cancel), i.e. ``M qdd = F u + (m a cos(th) thd^2, m a sin(th) thd^2, 0)``.


def _sled_states(rng: np.random.Generator, b: int) -> np.ndarray:
    return np.column_stack([rng.uniform(-5, 5, (b, 2)), rng.uniform(-np.pi, np.pi, b), rng.uniform(-3, 3, (b, 3))])


def _sled_params(rng: np.random.Generator, b: int) -> np.ndarray:
    # (m, I, a, v_ref), away from the defaults so no default is baked into a formula.
    return np.column_stack([rng.uniform(5, 40, b), rng.uniform(0.5, 5, b), rng.uniform(0.1, 0.8, b),
                            rng.uniform(0.5, 3, b)])


def _sled_mass_and_bias(s: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    th, thd = s[:, 2], s[:, 5]
    m, inertia, a = p[:, 0], p[:, 1], p[:, 2]
    sn, cs = np.sin(th), np.cos(th)
    mass = np.zeros((len(s), 3, 3))
    mass[:, 0, 0] = mass[:, 1, 1] = m
    mass[:, 0, 2] = mass[:, 2, 0] = -m * a * sn
    mass[:, 1, 2] = mass[:, 2, 1] = m * a * cs
    mass[:, 2, 2] = inertia + m * a**2
    forces = np.zeros((len(s), 3, 2))
    forces[:, 0, 0], forces[:, 1, 0], forces[:, 2, 1] = cs, sn, 1.0
    bias = np.column_stack([m * a * cs * thd**2, m * a * sn * thd**2, np.zeros(len(s))])
    return mass, forces, bias


def test_sled_dynamics_match_euler_lagrange() -> None:
    model = make_sled()
    rng = np.random.default_rng(0)
    s, p = _sled_states(rng, 30), _sled_params(rng, 30)
    mass, forces, bias = _sled_mass_and_bias(s, p)
    a0, y = model.dynamics(s, p)
    np.testing.assert_allclose(a0, np.linalg.solve(mass, bias[..., None])[..., 0], rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(y, np.linalg.solve(mass, forces), rtol=1e-10, atol=1e-12)


def test_sled_constraint_decoupling_and_energy() -> None:
    model = make_sled()
    rng = np.random.default_rng(1)
    s, p = _sled_states(rng, 30), _sled_params(rng, 30)
    th, xd, yd, thd = s[:, 2], s[:, 3], s[:, 4], s[:, 5]
    sn, cs = np.sin(th), np.cos(th)
    # No sideways slip of the blade; forward speed at v_ref.
    np.testing.assert_allclose(model.phi(s, p), np.column_stack([-sn * xd + cs * yd, cs * xd + sn * yd - p[:, 3]]),
                               atol=1e-12)
    # C = (d phi / d qd) M^-1 F: the slip is steered through the torque only, the speed through the thrust.
    m, inertia, a = p[:, 0], p[:, 1], p[:, 2]
    c, _ = model.decoupling(s, p)
    expected = np.zeros((30, 2, 2))
    expected[:, 0, 1] = -a / inertia
    expected[:, 1, 0] = 1 / m
    np.testing.assert_allclose(c, expected, rtol=1e-10, atol=1e-12)
    kinetic = m / 2 * ((xd - a * sn * thd) ** 2 + (yd + a * cs * thd) ** 2) + inertia / 2 * thd**2
    np.testing.assert_allclose(model.energy(s, p), kinetic, rtol=1e-10)


def test_sled_phi_decays_exponentially() -> None:
    model = make_sled()
    rng = np.random.default_rng(2)
    s0 = _sled_states(rng, 20)
    gains = np.array([0.7, 2.0])
    # dt = 2.5 ms: the sled turns at up to 3 rad/s, and RK4's error (which falls 16x per halving of dt
    # here) must stay below the decay check's 1e-5 relative tolerance over 5 s.
    tr = simulate(model, s0, 0.0025, 2000, feedback="continuous", gains=gains, record_every=20)
    assert not np.any(tr.flags)
    assert_exponential_decay(tr.t, tr.phi, gains)
