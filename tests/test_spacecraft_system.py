"""The spacecraft against facts derived by hand, in numpy, independently of the library.

* Euler's rigid-body equations ``J omegadot + omega x J omega = tau``, with the body angular
  velocity ``omega = E(q) qd`` of the ZYX Euler angles (``E`` itself checked against the definition
  ``R^T dR/dt = [omega]x`` of a hand-written ``R = Rz(psi) Ry(theta) Rx(varphi)``).
* The decoupling matrix ``C = J^-1`` (from ``d phi/d qd = E`` and ``Y = E^-1 J^-1``), the Lie
  derivative ``G`` from Euler's equations and ``zdot = z x omega``, hence
  ``u* = J (-K phi - G)``; the transversality measure is 1 wherever the angles are a chart.
* With no torque the kinetic energy and the inertial angular momentum ``R J omega`` are
  conserved, and a spin about the intermediate axis flips (Dzhanibekov) while one about the
  major axis does not.
* Theorem 2: ``phi(t) = exp(-K t) phi(0)`` under continuous feedback.
* On ``phi = 0``: ``z_3 = cos(tilt)`` solves ``z_3' = lam (1 - z_3^2)``, so
  ``z_3(t) = tanh(lam t + artanh z_3(0))``, and ``z_1 + i z_2`` turns at ``-Omega``.
"""

from __future__ import annotations

import numpy as np
import pytest

from vnhc_gym.mechanics import simulate
from vnhc_gym.systems.spacecraft import make_spacecraft

# --------------------------------------------------------------------------- hand-written kinematics


def rotation(q: np.ndarray) -> np.ndarray:
    """``R = Rz(psi) Ry(theta) Rx(varphi)`` (body to inertial), shape ``(B, 3, 3)``."""
    psi, th, ph = q[:, 0], q[:, 1], q[:, 2]
    one, zero = np.ones_like(psi), np.zeros_like(psi)
    rz = np.stack([np.cos(psi), -np.sin(psi), zero, np.sin(psi), np.cos(psi), zero, zero, zero, one], -1)
    ry = np.stack([np.cos(th), zero, np.sin(th), zero, one, zero, -np.sin(th), zero, np.cos(th)], -1)
    rx = np.stack([one, zero, zero, zero, np.cos(ph), -np.sin(ph), zero, np.sin(ph), np.cos(ph)], -1)
    return rz.reshape(-1, 3, 3) @ ry.reshape(-1, 3, 3) @ rx.reshape(-1, 3, 3)


def rate_matrix(q: np.ndarray) -> np.ndarray:
    """``E(q)`` with ``omega = E qd`` (columns: psid, thetad, varphid)."""
    th, ph = q[:, 1], q[:, 2]
    st, ct, sp, cp = np.sin(th), np.cos(th), np.sin(ph), np.cos(ph)
    zero, one = np.zeros_like(th), np.ones_like(th)
    return np.stack([-st, zero, one, ct * sp, cp, zero, ct * cp, -sp, zero], -1).reshape(-1, 3, 3)


def rate_matrix_dot(q: np.ndarray, qd: np.ndarray) -> np.ndarray:
    """``dE/dt`` along ``qd``."""
    th, ph, thd, phd = q[:, 1], q[:, 2], qd[:, 1], qd[:, 2]
    st, ct, sp, cp = np.sin(th), np.cos(th), np.sin(ph), np.cos(ph)
    zero = np.zeros_like(th)
    return np.stack([-ct * thd, zero, zero,
                     -st * sp * thd + ct * cp * phd, -sp * phd, zero,
                     -st * cp * thd - ct * sp * phd, -cp * phd, zero], -1).reshape(-1, 3, 3)


def mv(a: np.ndarray, x: np.ndarray) -> np.ndarray:
    return np.einsum("bij,bj->bi", a, x)


def vertical_in_body(q: np.ndarray) -> np.ndarray:
    """``z = R^T e_z``: the inertial vertical in body axes."""
    return rotation(q)[:, 2, :]


def states(rng: np.random.Generator, b: int, max_theta: float = 1.2) -> np.ndarray:
    """Any yaw and roll, pitch within ``max_theta`` of level (``cos theta >= 0.36``), rates up to 2 rad/s."""
    return np.column_stack([rng.uniform(-np.pi, np.pi, b), rng.uniform(-max_theta, max_theta, b),
                            rng.uniform(-np.pi, np.pi, b), rng.uniform(-2, 2, (b, 3))])


def params(rng: np.random.Generator, b: int) -> np.ndarray:
    """``(J1, J2, J3, Omega, lam)`` away from the defaults, in any order of the inertias, spin either way."""
    return np.column_stack([rng.uniform(0.5, 3.0, (b, 3)), rng.uniform(-2.0, 2.0, b), rng.uniform(0.3, 2.0, b)])


def off_constraint(rng: np.random.Generator, p: np.ndarray) -> np.ndarray:
    """Starts tilted by up to 60 deg (pitch and roll within 45 deg), any yaw, off the constraint by
    0.2 to 1 rad/s in each component (either sign): the episodes a task would draw."""
    b = p.shape[0]
    q = np.column_stack([rng.uniform(-np.pi, np.pi, b), rng.uniform(-np.pi / 4, np.pi / 4, (b, 2))])
    z = vertical_in_body(q)
    lam = p[:, 4]
    omega = np.column_stack([-lam * z[:, 1], lam * z[:, 0], p[:, 3]])
    omega += rng.uniform(0.2, 1.0, (b, 3)) * rng.choice([-1.0, 1.0], (b, 3))
    return np.hstack([q, np.linalg.solve(rate_matrix(q), omega[..., None])[..., 0]])


def phi_by_hand(s: np.ndarray, p: np.ndarray) -> np.ndarray:
    """``omega_perp + lam (z x e3)_perp`` and ``omega_3 - Omega``."""
    omega = mv(rate_matrix(s[:, :3]), s[:, 3:])
    z = vertical_in_body(s[:, :3])
    lam = p[:, 4]
    return np.column_stack([omega[:, 0] + lam * z[:, 1], omega[:, 1] - lam * z[:, 0], omega[:, 2] - p[:, 3]])


# --------------------------------------------------------------------------- the tests


def test_rate_matrix_is_the_body_angular_velocity() -> None:
    """The hand-written E against the definition ``R^T dR/dt = [omega]x`` (central differences)."""
    rng = np.random.default_rng(10)
    s = states(rng, 20)
    q, qd = s[:, :3], s[:, 3:]
    h = 1e-6
    skew = np.transpose(rotation(q), (0, 2, 1)) @ (rotation(q + h * qd) - rotation(q - h * qd)) / (2 * h)
    omega = mv(rate_matrix(q), qd)
    np.testing.assert_allclose(np.column_stack([skew[:, 2, 1], skew[:, 0, 2], skew[:, 1, 0]]), omega, atol=1e-8)
    np.testing.assert_allclose(skew + np.transpose(skew, (0, 2, 1)), 0.0, atol=1e-8)


def test_spacecraft_dynamics_match_euler_rigid_body_equations() -> None:
    model = make_spacecraft()
    rng = np.random.default_rng(0)
    s, p = states(rng, 40), params(rng, 40)
    tau = rng.uniform(-3, 3, (40, 3))
    q, qd = s[:, :3], s[:, 3:]
    qdd = model.acceleration(s, tau, p)
    omega = mv(rate_matrix(q), qd)
    omegadot = mv(rate_matrix_dot(q, qd), qd) + mv(rate_matrix(q), qdd)
    j = p[:, :3]
    np.testing.assert_allclose(omegadot, (tau - np.cross(omega, j * omega)) / j, rtol=1e-10, atol=1e-10)


def test_spacecraft_constraint_decoupling_and_transversality() -> None:
    model = make_spacecraft()
    rng = np.random.default_rng(1)
    s, p = states(rng, 40), params(rng, 40)
    j, omega_ref, lam = p[:, :3], p[:, 3], p[:, 4]
    np.testing.assert_allclose(model.phi(s, p), phi_by_hand(s, p), atol=1e-12)
    c, g = model.decoupling(s, p)
    np.testing.assert_allclose(c, np.einsum("bi,ij->bij", 1 / j, np.eye(3)), rtol=1e-10, atol=1e-10)
    # G = omegadot(tau = 0) + lam (zdot_2, -zdot_1, 0), with Euler's equations and zdot = z x omega.
    omega = mv(rate_matrix(s[:, :3]), s[:, 3:])
    z = vertical_in_body(s[:, :3])
    zdot = np.cross(z, omega)
    g_hand = -np.cross(omega, j * omega) / j + lam[:, None] * np.column_stack([zdot[:, 1], -zdot[:, 0], 0 * lam])
    np.testing.assert_allclose(g, g_hand, rtol=1e-10, atol=1e-10)
    gains = np.array([0.7, 2.0, 5.0])
    u = model.control(s, gains=gains, params=p)
    np.testing.assert_allclose(u, j * (-gains * phi_by_hand(s, p) - g_hand), rtol=1e-9, atol=1e-9)
    assert omega_ref.min() < 0 < omega_ref.max()  # either spin direction
    # |J_b|^2 = J_b M^-1 J_b^T = 1/J_b and |Y^a|^2 = f^a . Y^a = 1/J_a: the normalised C is the
    # identity, so the measure is 1 at every attitude where the angles are a chart, for any inertia.
    np.testing.assert_allclose(model.transversality(s, p), 1.0, rtol=1e-12)
    extreme = model.params(J1=1e-6, J2=1.0, J3=1e6)
    np.testing.assert_allclose(model.transversality(s, extreme), 1.0, rtol=1e-12)


def test_law_accurate_up_to_the_proposed_termination_pitch() -> None:
    """u* is a smooth function of (z, omega), but the compiled drift carries 1/cos(theta)^2 factors
    that cancel only in exact arithmetic, losing about eps / cos(theta)^2 = 7e-15 at |theta| = 80 deg
    (the proposed termination)."""
    model = make_spacecraft()
    rng = np.random.default_rng(5)
    s = states(rng, 40)
    s[:, 1] = np.deg2rad(80.0) * np.sign(rng.uniform(-1, 1, 40))
    p = np.tile(model.default_params, (40, 1))
    j, lam = p[:, :3], p[:, 4]
    omega = mv(rate_matrix(s[:, :3]), s[:, 3:])
    zdot = np.cross(vertical_in_body(s[:, :3]), omega)
    g_hand = -np.cross(omega, j * omega) / j + lam[:, None] * np.column_stack([zdot[:, 1], -zdot[:, 0], 0 * lam])
    want = j * (-5.0 * phi_by_hand(s, p) - g_hand)
    got = model.control(s, gains=5.0, params=p)
    assert np.max(np.abs(got - want)) < 1e-12 * np.max(np.abs(want))


def test_free_body_conserves_energy_and_angular_momentum() -> None:
    model = make_spacecraft()
    rng = np.random.default_rng(2)
    s0, p = states(rng, 20, max_theta=0.8), params(rng, 20)
    # dt = 0.5 ms: these free tumbles pass within 3 deg of gimbal lock, where the angles' rates grow
    # as 1/cos(theta) and RK4's error in the energy reaches 8e-9 at dt = 2 ms (it falls 16x per halving).
    tr = simulate(model, s0, 0.0005, 10000, feedback="open", params=p, record_every=200)  # 5 s
    assert not np.any(tr.flags)
    assert np.abs(tr.states[..., 1]).max() > np.deg2rad(85)
    q, qd = tr.states[..., :3].reshape(-1, 3), tr.states[..., 3:].reshape(-1, 3)
    j = np.broadcast_to(p[:, :3], tr.states.shape[:2] + (3,)).reshape(-1, 3)
    omega = mv(rate_matrix(q), qd)
    kinetic = (0.5 * np.sum(j * omega**2, axis=1)).reshape(tr.energy.shape)
    np.testing.assert_allclose(tr.energy, kinetic, rtol=1e-12)
    np.testing.assert_allclose(tr.energy, tr.energy[:1].repeat(len(tr.t), 0), rtol=1e-9)
    momentum = mv(rotation(q), j * omega).reshape(tr.states.shape[:2] + (3,))
    scale = np.linalg.norm(momentum[0], axis=1)[None, :, None]
    np.testing.assert_allclose(momentum / scale, (momentum[:1] / scale).repeat(len(tr.t), 0), atol=1e-9)


def test_free_body_intermediate_axis_flips() -> None:
    """Defaults J = (1, 1.5, 2): a spin about the intermediate axis 2, perturbed by 0.01 rad/s, flips
    (its growth rate Omega sqrt((J2 - J1)(J3 - J2) / (J1 J3)) = 0.71/s at 2 rad/s); one about the
    major axis 3 stays.  Both start with the spin axis vertical, far from gimbal lock, and keep
    energy and momentum through the flip."""
    model = make_spacecraft()
    q = np.array([[0.0, 0.0, np.pi / 2], [0.0, 0.0, 0.0]])  # body axis 2 vertical; body axis 3 vertical
    omega = np.array([[0.01, 2.0, 0.01], [0.01, 0.01, 2.0]])
    qd = np.linalg.solve(rate_matrix(q), omega[..., None])[..., 0]
    tr = simulate(model, np.hstack([q, qd]), 0.002, 10000, feedback="open", record_every=25)  # 20 s
    assert not np.any(tr.flags)
    qs, qds = tr.states[..., :3].reshape(-1, 3), tr.states[..., 3:].reshape(-1, 3)
    w = mv(rate_matrix(qs), qds).reshape(tr.states.shape[:2] + (3,))
    assert w[:, 0, 1].min() < -1.9  # the intermediate-axis spin has turned over
    assert np.all(np.abs(w[:, 1, 2] - 2.0) < 0.01)  # the major-axis spin has not
    np.testing.assert_allclose(tr.energy, tr.energy[:1].repeat(len(tr.t), 0), rtol=1e-9)
    assert np.abs(tr.states[:, :, 1]).max() < np.deg2rad(40)  # |sin theta| = |J1 w1| / |h| <= 1/sqrt(3)


@pytest.mark.parametrize("gains", [1.0, 5.0, (2.0, 3.0, 5.0)])
def test_spacecraft_phi_decays_exponentially(gains: float | tuple[float, ...]) -> None:
    model = make_spacecraft()
    rng = np.random.default_rng(3)
    p = params(rng, 20)
    s0 = off_constraint(rng, p)
    k = np.broadcast_to(np.asarray(gains, dtype=float), (3,))
    tr = simulate(model, s0, 0.002, 1500, feedback="continuous", gains=k, params=p, record_every=10)  # 3 s
    assert not np.any(tr.flags)
    assert np.abs(tr.states[..., 1]).max() < np.deg2rad(80)  # clear of gimbal lock, where RK4 in the angles degrades
    np.testing.assert_allclose(tr.phi[0], phi_by_hand(s0, p), atol=1e-12)
    assert np.all(np.abs(tr.phi[0]) >= 0.2 - 1e-12)
    expected = np.exp(-tr.t[:, None, None] * k) * tr.phi[0]
    # Relative while exp(-k t) >= 1e-3; after that an absolute floor of 1e-9 of |phi(0)| (RK4's
    # truncation error does not shrink with phi).
    err = np.abs(tr.phi - expected) / (np.abs(expected) + 1e-3 * np.abs(tr.phi[0]))
    assert err.max() < 1e-6, f"phi deviates from exp(-k t) phi(0) by {err.max():.2e}"


def test_reduced_dynamics_on_the_constraint() -> None:
    """On phi = 0 the spin axis rises to the vertical as z_3(t) = tanh(lam t + artanh z_3(0)), whatever
    the inertia and the spin; the horizontal part z_1 + i z_2 of the vertical turns at -Omega in
    the body; the pitch stays below the initial tilt."""
    model = make_spacecraft()
    rng = np.random.default_rng(4)
    b = 20
    p = params(rng, b)
    lam, omega_ref = p[:, 4], p[:, 3]
    q0 = np.column_stack([rng.uniform(-np.pi, np.pi, b), rng.uniform(-0.7, 0.7, (b, 2))])
    z0 = vertical_in_body(q0)
    omega0 = np.column_stack([-lam * z0[:, 1], lam * z0[:, 0], omega_ref])  # phi = 0
    qd0 = np.linalg.solve(rate_matrix(q0), omega0[..., None])[..., 0]
    s0 = np.hstack([q0, qd0])
    np.testing.assert_allclose(model.phi(s0, p), 0.0, atol=1e-14)
    tr = simulate(model, s0, 0.002, 2500, feedback="continuous", gains=5.0, params=p, record_every=25)  # 5 s
    assert not np.any(tr.flags)
    assert np.abs(tr.phi).max() < 1e-10
    z = vertical_in_body(tr.states[..., :3].reshape(-1, 3)).reshape(tr.states.shape[:2] + (3,))
    t = tr.t[:, None]
    np.testing.assert_allclose(z[..., 2], np.tanh(lam * t + np.arctanh(z0[:, 2])), rtol=1e-8, atol=1e-10)
    w = z[..., 0] + 1j * z[..., 1]
    turned = np.angle(w * np.conj(w[0]) * np.exp(1j * omega_ref * t))
    np.testing.assert_allclose(turned, 0.0, atol=1e-7)
    tilt0 = np.arccos(z0[:, 2])
    assert np.all(np.abs(tr.states[..., 1]) <= tilt0 + 1e-12)
