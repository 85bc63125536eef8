"""Tests of vnhc_gym.baselines: the geometric law (plain and sampled), the observer law, the adaptive
law, the zero and random policies, and the tuning of the classical baselines.

Expected values come from facts that do not depend on the code under test: the closed-form laws
of the env cards written out in numpy from the documented observation layouts, the defining
property of the sampled-data law (``phi`` after one control period is ``exp(-k dt) phi``), the
true state and parameters in ``info``, and the seed ranges of the evaluation protocol.
"""

from __future__ import annotations

import itertools
from types import SimpleNamespace
from typing import Any

import gymnasium as gym
import numpy as np
import pytest

import vnhc_gym  # noqa: F401  (registers the environments)
import vnhc_gym.evaluation
import vnhc_gym.evaluation.protocol
from vnhc_gym.baselines import (
    CLASSICAL,
    DEFAULT_GAIN,
    AdaptiveController,
    GeometricController,
    ObserverController,
    RandomPolicy,
    ZeroPolicy,
    make_classical,
    task_of,
    tune,
)
from vnhc_gym.baselines.tuning import SELECTION_METRIC
from vnhc_gym.evaluation import TEST_SEED, VALIDATION_SEED, evaluate
from vnhc_gym.tasks import env_id, env_ids

ENVS = env_ids("v1")
FLOCK = env_id("flocking")
USV = env_id("usv")


def _short(e: str) -> str:
    return e.removeprefix("vnhc_gym/")


def _vec(env: str, n: int, **kwargs: Any) -> gym.vector.VectorEnv:
    return gym.make_vec(env, num_envs=n, vectorization_mode="vector_entry_point", **kwargs)


def _diverse_batch(env: str, n: int = 16, steps: int = 3, **kwargs: Any) -> tuple[np.ndarray, dict, Any]:
    """Observations and infos of ``n`` held-out episodes after a few random actions (not on the manifold)."""
    venv = _vec(env, n, **kwargs)
    obs, info = venv.reset(seed=TEST_SEED)
    rng = np.random.default_rng(0)
    for _ in range(steps):
        a = rng.uniform(-0.3, 0.3, venv.action_space.shape).astype(np.float32)
        obs, _, _, _, info = venv.step(a)
    return obs, info, venv


# --------------------------------------------------------------------------- the law beats no control
@pytest.mark.parametrize("env", ENVS, ids=_short)
def test_law_lowers_mean_phi_100_fold_against_no_control(env: str) -> None:
    zero = evaluate(ZeroPolicy, env, "nominal", n_episodes=4, seed=TEST_SEED)
    law = evaluate(GeometricController, env, "nominal", n_episodes=4, seed=TEST_SEED)
    assert np.mean(zero.metrics["mean_abs_phi"]) >= 100 * np.mean(law.metrics["mean_abs_phi"])
    assert not law.metrics["terminated"].any()


# --------------------------------------------------------------------------- the closed-form laws
def _flocking_law(o: np.ndarray, n_agents: int, m: np.ndarray, g: float, k: np.ndarray,
                  consistent_phi: bool = False) -> np.ndarray:
    """The card's law from the observation: ``u*_b = m_b [g (e_x - r_bx) - k s p_b] / (e_x - e_z)``,
    ``s = exp(5 o[2(N-1)+2])``, ``p_b = o[2(N-1)+3+b]`` (or ``e_x r_bz - r_bx e_z`` recomputed)."""
    o = o.astype(np.float64)
    nf = n_agents - 1
    rx, rz = o[:, 0:2 * nf:2], o[:, 1:2 * nf:2]
    ex, ez = o[:, 2 * nf:2 * nf + 1], o[:, 2 * nf + 1:2 * nf + 2]
    s = np.exp(5.0 * o[:, 2 * nf + 2:2 * nf + 3])
    p = ex * rz - rx * ez if consistent_phi else o[:, 2 * nf + 3:3 * nf + 3]
    return m[None, :nf] * (g * (ex - rx) - k[None, :] * s * p) / (ex - ez)


@pytest.mark.parametrize(("kwargs", "gain"), [
    ({}, 5.0),
    ({}, 1.7),
    ({"n_agents": 5, "masses": [1.0, 2.5, 0.7, 4.0, 3.0], "g": 9.81}, [1.0, 2.0, 3.0, 0.5]),
], ids=["default", "gain-1.7", "five-agents"])
def test_flocking_law_is_the_closed_form(kwargs: dict, gain: Any) -> None:
    obs, info, venv = _diverse_batch(FLOCK, **kwargs)
    n = kwargs.get("n_agents", 4)
    masses = np.broadcast_to(np.asarray(kwargs.get("masses", 2.0), dtype=float), (n,))
    g = float(kwargs.get("g", 10.0))
    k = np.broadcast_to(np.asarray(gain, dtype=float), (n - 1,))
    ctrl = GeometricController(venv, gain=gain)
    u, singular = ctrl.force(obs)
    assert u.shape == (16, n - 1) and not singular.any()
    # The float32 observation's phi entry is its velocities' phi up to rounding.
    expected = _flocking_law(obs, n, masses, g, k)
    np.testing.assert_allclose(u, expected, rtol=1e-5, atol=1e-5 * np.abs(expected).max())
    # With the phi entries recomputed in float64 from the observed velocities, to rounding error.
    exact = obs.astype(np.float64)
    nf = n - 1
    exact[:, 2 * nf + 3:] = exact[:, 2 * nf:2 * nf + 1] * exact[:, 1:2 * nf:2] \
        - exact[:, 0:2 * nf:2] * exact[:, 2 * nf + 1:2 * nf + 2]
    u_exact, _ = ctrl.force(exact)
    np.testing.assert_allclose(u_exact, _flocking_law(obs, n, masses, g, k, consistent_phi=True), rtol=1e-10,
                               atol=1e-10 * np.abs(expected).max())
    # From the true state in info (x.., z.., xd.., zd..; leader last).
    st = info["state"]
    xd, zd = st[:, 2 * n:3 * n], st[:, 3 * n:]
    phi = xd[:, -1:] * zd[:, :nf] - xd[:, :nf] * zd[:, -1:]
    np.testing.assert_allclose(phi, info["phi"], rtol=1e-12, atol=1e-12)
    u_true = masses[None, :nf] * (g * (xd[:, -1:] - xd[:, :nf]) - k * phi) / (xd[:, -1:] - zd[:, -1:])
    np.testing.assert_allclose(u, u_true, rtol=1e-4, atol=1e-4 * np.abs(u_true).max())
    # The action is the force over the bound, clipped, as float32.
    a, state = ctrl.predict(obs)
    assert state is None and a.dtype == np.float32
    np.testing.assert_allclose(a, np.clip(expected / venv.unwrapped.task.force_bound, -1, 1), rtol=1e-5, atol=1e-6)
    venv.close()


def _usv_law(o: np.ndarray, m: float, k: float, phi_from_entry: bool = False) -> np.ndarray:
    """The card's law ``u* = -m [k phi + thetad (xd cos + yd sin)]`` from the observation (velocities,
    turn rate, current and phi are stored over 2)."""
    o = o.astype(np.float64)
    th = np.arctan2(o[:, 1], o[:, 0])
    c, s = np.cos(th), np.sin(th)
    xd, yd, thd = 2 * o[:, 2], 2 * o[:, 3], 2 * o[:, 4]
    c1, c2 = 2 * o[:, 5], 2 * o[:, 6]
    phi = 2 * o[:, 9] if phi_from_entry else s * xd - c * yd + c * c2 - s * c1
    return -m * (k * phi + thd * (xd * c + yd * s))


@pytest.mark.parametrize(("kwargs", "gain"), [({}, 5.0), ({"mass": 7.0, "inertia": 3.0}, 2.5),
                                              ({"current": "anticyclone"}, 1.0)],
                         ids=["default", "mass-7", "anticyclone"])
def test_usv_law_is_the_closed_form(kwargs: dict, gain: float) -> None:
    obs, info, venv = _diverse_batch(USV, **kwargs)
    m = float(kwargs.get("mass", 10.0))
    ctrl = GeometricController(venv, gain=gain)
    u, singular = ctrl.force(obs)
    assert u.shape == (16, 1) and not singular.any()
    expected = _usv_law(obs, m, gain)
    np.testing.assert_allclose(u[:, 0], expected, rtol=1e-10, atol=1e-10 * np.abs(expected).max())
    # phi from its own (float32) entry: the same up to rounding.
    np.testing.assert_allclose(u[:, 0], _usv_law(obs, m, gain, phi_from_entry=True), rtol=1e-5,
                               atol=1e-5 * np.abs(expected).max())
    # From the true state (x, y, theta, xd, yd, thetad) and the true phi.
    st = info["state"]
    u_true = -m * (gain * info["phi"][:, 0] + st[:, 5] * (st[:, 3] * np.cos(st[:, 2]) + st[:, 4] * np.sin(st[:, 2])))
    np.testing.assert_allclose(u[:, 0], u_true, rtol=1e-4, atol=1e-4 * np.abs(u_true).max())
    venv.close()


@pytest.mark.parametrize("env", ENVS, ids=_short)
def test_sampled_variant_reaches_the_exponential_target_in_one_period(env: str) -> None:
    """The sampled-data law holds the control that makes phi(t + dt) = exp(-k dt) phi(t) on the
    nominal model; the plain held law misses that target by the zero-order-hold error."""
    k = 5.0
    rel_err = {}
    for variant in ("plain", "sampled"):
        venv = _vec(env, 8)
        ctrl = GeometricController(venv, gain=k, variant=variant)
        assert ctrl.name == ("geometric" if variant == "plain" else "geometric-sampled")
        obs, info = venv.reset(seed=TEST_SEED)
        decay = np.exp(-k * venv.unwrapped.dt)
        errs = []
        for _ in range(20):
            phi0 = info["phi"].copy()
            a, _ = ctrl.predict(obs)
            ok = ~ctrl.last_saturated  # the target holds where the force is not clipped
            assert ok.sum() >= 6 and not ctrl.last_singular.any()
            obs, _, _, _, info = venv.step(a)
            errs.append(np.abs(info["phi"][ok] - decay * phi0[ok]).max() / np.abs(phi0[ok]).max())
        rel_err[variant] = max(errs)
        venv.close()
    assert rel_err["sampled"] < 1e-3
    assert rel_err["plain"] > 10 * rel_err["sampled"]


@pytest.mark.parametrize("env", ENVS, ids=_short)
def test_batched_predict_equals_row_by_row_and_single_env(env: str) -> None:
    obs, _, venv = _diverse_batch(env, n=6)
    single = gym.make(env)
    for variant in ("plain", "sampled"):
        ctrl = GeometricController(venv, variant=variant)
        batch, state = ctrl.predict(obs)
        assert state is None and batch.dtype == np.float32 and batch.shape == (6, venv.single_action_space.shape[0])
        assert np.all(np.abs(batch) <= 1)
        rows = np.stack([ctrl.predict(o)[0] for o in obs])
        np.testing.assert_allclose(batch, rows, rtol=1e-6, atol=1e-7)
        from_single = GeometricController(single, variant=variant)
        np.testing.assert_array_equal(from_single.force_bound, ctrl.force_bound)
        np.testing.assert_array_equal(from_single.predict(obs)[0], batch)
        assert ctrl.n_rows == 6 + 6  # the batch, then six single rows
    venv.close()
    single.close()


def test_singular_decoupling_gives_zero_action_and_is_reported() -> None:
    """Flocking's C is singular when the leader moves along the diagonal (e_x == e_z)."""
    env = gym.make(FLOCK)
    good, _ = env.reset(seed=TEST_SEED)
    bad = good.copy()
    bad[6] = bad[7] = np.float32(np.sqrt(0.5))
    for variant in ("plain", "sampled"):
        ctrl = GeometricController(env, variant=variant)
        a, _ = ctrl.predict(np.stack([bad, good]))
        assert np.all(np.isfinite(a))
        np.testing.assert_array_equal(a[0], 0.0)
        assert np.any(a[1] != 0.0)
        assert ctrl.last_singular.tolist() == [True, False]
        assert ctrl.n_singular == 1
    env.close()


def test_saturation_is_clipped_and_counted() -> None:
    env = gym.make(FLOCK, scenario="saturated")
    obs, _ = env.reset(seed=TEST_SEED)
    ctrl = GeometricController(env)
    u, _ = ctrl.force(obs)
    a, _ = ctrl.predict(obs)
    ratio = u[0] / env.unwrapped.task.force_bound
    assert np.any(np.abs(ratio) > 1)  # 12.5 N is far below what the law asks at the start
    np.testing.assert_allclose(a, np.clip(ratio, -1, 1), rtol=1e-6)
    assert ctrl.last_saturated.tolist() == [True] and ctrl.n_saturated == 1
    env.close()


def test_constructor_and_observation_checks() -> None:
    env = gym.make(USV)
    for pol in (GeometricController(env), ObserverController(env), AdaptiveController(env), ZeroPolicy(env),
                RandomPolicy(env, seed=0)):
        with pytest.raises(ValueError, match=r"\(14,\)"):
            pol.predict(np.zeros(13))
        with pytest.raises(ValueError, match=r"\(n, 14\)"):
            pol.predict(np.zeros((2, 3, 14)))
    with pytest.raises(ValueError, match="variant"):
        GeometricController(env, variant="exact")
    with pytest.raises(ValueError, match="gain"):
        GeometricController(env, gain=-1.0)
    with pytest.raises(ValueError, match="gain"):
        GeometricController(env, gain=[1.0, 2.0])  # the USV has one constraint component
    with pytest.raises(ValueError, match="iters"):
        GeometricController(env, iters=-1)
    with pytest.raises(ValueError, match="alpha"):
        ObserverController(env, alpha=0.0)
    with pytest.raises(ValueError, match="prior"):
        AdaptiveController(env, prior=-1.0)
    with pytest.raises(TypeError, match="task"):
        GeometricController(gym.make("Pendulum-v1"))
    with pytest.raises(TypeError):
        ZeroPolicy()
    with pytest.raises(ValueError, match="episode_start"):
        GeometricController(env).predict(np.zeros((2, 14)), episode_start=[True])
    # A wrapper that changes the spaces is refused (the law reads the raw observation).
    with pytest.raises(ValueError, match="spaces"):
        GeometricController(gym.wrappers.FlattenObservation(gym.wrappers.FrameStackObservation(env, 2)))
    assert task_of(gym.wrappers.ClipAction(env)) is env.unwrapped.task
    env.close()


def test_zero_and_random_policies() -> None:
    env = gym.make(FLOCK)
    obs, _ = env.reset(seed=0)
    a, state = ZeroPolicy(env).predict(obs)
    assert state is None and a.dtype == np.float32 and a.shape == (3,) and not a.any()
    r1 = RandomPolicy(env, seed=4).predict(np.stack([obs, obs]))[0]
    r2 = RandomPolicy(env, seed=4).predict(np.stack([obs, obs]))[0]
    r3 = RandomPolicy(env, seed=5).predict(np.stack([obs, obs]))[0]
    assert r1.shape == (2, 3) and r1.dtype == np.float32 and np.all(np.abs(r1) <= 1)
    np.testing.assert_array_equal(r1, r2)
    assert not np.array_equal(r1, r3)
    assert ZeroPolicy(obs_dim=5, act_dim=2).predict(np.zeros(5))[0].shape == (2,)
    env.close()


# --------------------------------------------------------------------------- the observer
#: The observer's default blend (weight alpha on each new observation) cannot hold an estimate of an
#: open-loop unstable plant: the cart-pole's pole departs from the upright at sqrt(3 g / 4 l) =
#: 3.8 1/s, a factor 1.21 per 0.05 s step, faster than the blend pulls the estimate back.
OBSERVER_ENVS = [pytest.param(e, marks=pytest.mark.xfail(strict=True, reason="open-loop unstable plant"))
                 if e.startswith("vnhc_gym/CartPoleBalance") else e for e in ENVS]


@pytest.mark.parametrize("env", OBSERVER_ENVS, ids=_short)
def test_observer_converges_on_a_noiseless_rollout(env: str) -> None:
    """Started from a wrong first observation, the estimate's phi converges to the true phi (and,
    where the controller's model is the environment's own, its velocities to the true ones)."""
    n = 4
    venv = _vec(env, n)
    task = venv.unwrapped.task
    ctrl = ObserverController(venv)
    nq = ctrl.model.n
    exact_model = task.controller_model() is task.model
    obs, info = venv.reset(seed=TEST_SEED)
    rng = np.random.default_rng(0)
    phi_err, vel_err = [], []
    for t in range(400):
        seen = obs + (0.2 * rng.standard_normal(obs.shape)).astype(np.float32) if t == 0 else obs
        a, _ = ctrl.predict(seen, episode_start=np.full(n, t == 0))
        x, p = ctrl._x, ctrl._p
        phi_err.append(np.abs(ctrl.model.phi(x, p) - info["phi"]).max(axis=1))
        ref, _ = task.controller_inputs(obs)
        vel_err.append(np.abs(x[:, nq:] - ref[:, nq:]).max(axis=1))
        obs, _, term, trunc, info = venv.step(a)
        assert not term.any()
    phi_err, vel_err = np.array(phi_err), np.array(vel_err)
    shows = phi_err[0] > 1e-2  # the perturbation shows (in most episodes: it may hit phi little)
    assert shows.sum() >= n - 1
    assert np.all(phi_err[100][shows] < phi_err[0][shows])
    assert np.all(phi_err[-1] < 1e-2 * max(phi_err[0].max(), 1e-2))
    if exact_model:
        assert np.all(vel_err[-1] < 1e-3 * vel_err[0])
    venv.close()


@pytest.mark.parametrize("env", OBSERVER_ENVS, ids=_short)
def test_observer_lowers_the_laws_phi_under_noise(env: str) -> None:
    law = evaluate(GeometricController, env, "noisy", n_episodes=4, seed=TEST_SEED)
    obs = evaluate(ObserverController, env, "noisy", n_episodes=4, seed=TEST_SEED)
    assert obs.policy == "observer"
    ratio = np.mean(obs.metrics["mean_abs_phi"]) / np.mean(law.metrics["mean_abs_phi"])
    assert ratio < 1.0
    if env == FLOCK:  # the clear case: the noise on the leader's log-speed is amplified by s = |v_N|
        assert ratio < 0.5


def test_observer_restarts_rows_where_an_episode_starts() -> None:
    venv = _vec(FLOCK, 3, scenario="noisy")
    ctrl = ObserverController(venv, alpha=0.1)
    obs, _ = venv.reset(seed=TEST_SEED)
    ctrl.predict(obs, episode_start=np.ones(3, dtype=bool))
    for _ in range(5):
        obs, *_ = venv.step(ctrl.predict(obs)[0])
    starts = np.array([False, True, False])
    ctrl.predict(obs, episode_start=starts)
    ref, _ = venv.unwrapped.task.controller_inputs(obs)
    np.testing.assert_array_equal(ctrl._x[1], ref[1])  # restarted from the observation
    assert not np.array_equal(ctrl._x[0], ref[0])  # filtered
    ctrl.reset()
    ctrl.predict(obs)
    np.testing.assert_array_equal(ctrl._x, ref)
    venv.close()


# --------------------------------------------------------------------------- the adaptive law
def _true_log_ratios(task: Any, true_params: np.ndarray) -> np.ndarray:
    names = task.model.param_names
    return np.stack([np.log(true_params[:, names.index(k)] / task.nominal[names.index(k)]) for k in task.uncertain],
                    axis=1)


@pytest.mark.parametrize("env", ENVS, ids=_short)
def test_adaptive_estimates_move_towards_the_true_parameters(env: str) -> None:
    n = 6
    venv = _vec(env, n, scenario="mismatch")
    task = venv.unwrapped.task
    ctrl = AdaptiveController(venv)
    obs, info = venv.reset(seed=TEST_SEED)
    target = _true_log_ratios(task, info["params"])
    assert np.all(np.abs(target).sum(axis=1) > 0.05)  # the scenario does perturb them
    errors = []
    for t in range(100):
        a, _ = ctrl.predict(obs, episode_start=np.full(n, t == 0))
        errors.append(np.abs(ctrl._theta - target).sum(axis=1))
        obs, _, term, _, info = venv.step(a)
        assert not term.any()
    errors = np.array(errors)
    np.testing.assert_array_equal(errors[0], np.abs(target).sum(axis=1))  # starts at the nominal values
    # Over the episodes together: an episode's excitation decides how fast its parameters show.
    assert errors[20].sum() < 0.5 * errors[0].sum()
    assert errors[-1].sum() < 0.3 * errors[0].sum()
    assert np.all(errors[-1] < errors[0])
    venv.close()


def test_the_adaptive_update_is_the_kalman_formula_on_the_steps_derivative() -> None:
    """One update of the adaptive law's filter on the boat (a frame that moves, three parameters)
    equals the Kalman formula written out in numpy, with the prediction's derivative in the
    log-ratios by central differences of the model's own step: theta + P H^T (H P H^T + R)^-1 (y - h)."""
    import jax

    from vnhc_gym.baselines.adaptive import correct_estimate

    task = gym.make(USV).unwrapped.task
    model, index = task.controller_model(), [task.controller_model().param_names.index(k) for k in task.uncertain]
    rng = np.random.default_rng(4)
    x = np.array([0.0, 0.0, 0.3, 0.8, -0.2, 0.1])
    p = model.default_params.copy()
    u = np.array([0.7])
    dt, sub = float(task.config.dt), int(task.config.substeps)
    truth = p.copy()
    truth[index] *= [1.2, 0.9, 1.1]
    y = task.recenter(model.step(x[None], dt, u=u[None], params=truth[None], substeps=sub)[0], p[None])[0][0]
    theta, cov, noise = rng.normal(0.0, 0.05, 3), np.diag([0.09, 0.04, 0.06]), 1e-3

    def predict(th: np.ndarray) -> np.ndarray:
        q = p.copy()
        q[index] *= np.exp(th)
        nxt = model.step(x[None], dt, u=u[None], params=q[None], substeps=sub)[0]
        return task.recenter(nxt, p[None])[0][0]

    h = np.stack([(predict(theta + e) - predict(theta - e)) / 2e-6 for e in 1e-6 * np.eye(3)], axis=1)
    s = h @ cov @ h.T + noise**2 * np.eye(6)
    expected = theta + cov @ h.T @ np.linalg.solve(s, y - predict(theta))
    with jax.enable_x64(True):
        rows = (jax.numpy.asarray(a) for a in (theta, cov, x, p, u, y))
        got, new_cov = correct_estimate(task.controller_functions(), task.frame_functions()[0], sub, tuple(index),
                                        task.angles, *rows, task.args, dt, noise, 0.0)
    np.testing.assert_allclose(np.asarray(got), expected, rtol=1e-5, atol=1e-8)
    np.testing.assert_allclose(np.asarray(new_cov), cov - cov @ h.T @ np.linalg.solve(s, h @ cov), rtol=1e-5,
                               atol=1e-10)


def test_adaptive_law_lowers_the_usv_phi_under_mismatch() -> None:
    law = evaluate(GeometricController, USV, "mismatch", n_episodes=4, seed=TEST_SEED)
    adaptive = evaluate(AdaptiveController, USV, "mismatch", n_episodes=4, seed=TEST_SEED)
    assert np.mean(adaptive.metrics["mean_abs_phi"]) < 0.2 * np.mean(law.metrics["mean_abs_phi"])
    assert np.mean(adaptive.metrics["late_abs_phi"]) < 0.1 * np.mean(law.metrics["late_abs_phi"])


# --------------------------------------------------------------------------- classical baselines and tuning
def test_make_classical_builds_each_baseline_by_name() -> None:
    env = gym.make(USV)
    from vnhc_gym.baselines.actuated import ActuatedLaw
    from vnhc_gym.baselines.kalman import KalmanController
    from vnhc_gym.baselines.mpc import MPCController
    from vnhc_gym.baselines.safety import SafeLaw

    expected = {"law": GeometricController, "tuned_law": GeometricController, "observer": ObserverController,
                "adaptive": AdaptiveController, "mpc": MPCController, "safe_law": SafeLaw,
                "kalman": KalmanController, "actuated_law": ActuatedLaw, "actuated_nominal": ActuatedLaw,
                "actuated_dob": ActuatedLaw}
    assert set(CLASSICAL) == set(expected)
    for name, cls in expected.items():
        pol = make_classical(name, env)
        assert type(pol) is cls and pol.name == name
    assert make_classical("law", env).gain.tolist() == [DEFAULT_GAIN]
    assert make_classical("observer", env, gain=2.0, alpha=0.1).alpha == 0.1
    with pytest.raises(ValueError, match="unknown classical baseline"):
        make_classical("pid", env)
    env.close()


class _SeedLog:
    """A stand-in for ``evaluate`` that records the episode seeds it is asked for and runs short
    real evaluations (1 s episodes), so tuning stays fast and still scores real rollouts."""

    def __init__(self, real: Any, fake: bool = False) -> None:
        self.real = real
        self.fake = fake
        self.calls: list[tuple[int, int]] = []

    def __call__(self, policy: Any, env: str, scenario: str = "nominal", n_episodes: int = 10,
                 seed: int = TEST_SEED, **kwargs: Any) -> Any:
        self.calls.append((seed, n_episodes))
        if self.fake:
            point = float(len(self.calls))
            return SimpleNamespace(metrics={SELECTION_METRIC: np.full(n_episodes, point),
                                            "success": np.ones(n_episodes)}, policy="fake")
        return self.real(policy, env, scenario, n_episodes=n_episodes, seed=seed, **{**kwargs, "max_time": 1.0})


def _patch_evaluate(monkeypatch: pytest.MonkeyPatch, log: _SeedLog) -> None:
    monkeypatch.setattr(vnhc_gym.evaluation, "evaluate", log)
    monkeypatch.setattr(vnhc_gym.evaluation.protocol, "evaluate", log)


@pytest.mark.parametrize("name", sorted(CLASSICAL))
def test_tuning_reads_only_validation_seeds_and_keeps_the_best(name: str, monkeypatch: pytest.MonkeyPatch) -> None:
    log = _SeedLog(evaluate)
    _patch_evaluate(monkeypatch, log)
    # Each where it can act (the actuated laws only where the structure is hidden: `applicable`).
    scenario = {"observer": "noisy", "adaptive": "mismatch", "actuated_law": "delay", "actuated_nominal": "lag",
                "actuated_dob": "unmodelled"}.get(name, "nominal")
    best, table = tune(name, USV, scenario, n_episodes=3)
    _, grid = CLASSICAL[name]
    assert len(log.calls) == len(table) == int(np.prod([len(v) for v in grid.values()]))
    for seed, n in log.calls:
        assert VALIDATION_SEED <= seed and seed + n - 1 < TEST_SEED
        assert n == 3
    # Every setting of the grid is scored once, and the best is the highest score (the first at a tie).
    keys = sorted(grid)
    assert [tuple(row[k] for k in keys) for row in table] == list(itertools.product(*(grid[k] for k in keys)))
    scores = [row["score"] for row in table]
    assert all(0 <= x <= 1 for x in scores)
    assert best == {k: table[int(np.argmax(scores))][k] for k in keys}


def test_tuning_cannot_be_pointed_at_test_seeds(monkeypatch: pytest.MonkeyPatch) -> None:
    log = _SeedLog(evaluate, fake=True)
    _patch_evaluate(monkeypatch, log)
    for kwargs in ({"n_episodes": TEST_SEED - VALIDATION_SEED + 5}, {"seed": TEST_SEED, "n_episodes": 3}):
        try:
            tune("law", USV, "nominal", **kwargs)
        except ValueError:
            continue
        assert all(seed + n - 1 < TEST_SEED for seed, n in log.calls), log.calls


def test_shipped_settings_cover_every_task_scenario_and_baseline() -> None:
    """Every shipped task has tuned settings in every scenario for every classical baseline and the
    oracle, each setting one of its tuning grid's candidates (so the benchmark's "tuned" rows are
    tuned, and a new task cannot silently fall back to the k = 5 law).  A setting a cell leaves out
    takes the class's default, which must then be one of the grid's candidates too."""
    import inspect

    from vnhc_gym.baselines.tuning import CLASSICAL, REFERENCE
    from vnhc_gym.benchmark import settings
    from vnhc_gym.envs.config import SCENARIOS
    from vnhc_gym.tasks import shipped_tasks

    table = settings()
    benchmarked = ("law", "tuned_law", "observer", "adaptive", "oracle")  # the benchmark's tuned rows
    for task in shipped_tasks():
        for scenario in SCENARIOS:
            cell = table.get(task, {}).get(scenario)
            assert cell is not None, f"no tuned settings for {task}/{scenario}"
            for name in benchmarked:
                cls, grid = {**CLASSICAL, **REFERENCE}[name]
                assert set(cell[name]) <= set(grid) and "gain" in cell[name], (task, scenario, name)
                for key, value in cell[name].items():
                    assert value in grid[key], (task, scenario, name, key, value)
                defaults = inspect.signature(cls).parameters
                for key in set(grid) - set(cell[name]):
                    assert defaults[key].default in grid[key], (task, scenario, name, key)


def test_the_tuned_law_tunes_its_variant_and_chooses_the_sampled_law_where_the_hold_limits_the_gain() -> None:
    """On the cart-pole's coarse control period (0.1 s) the held law loses ``phi`` once ``k dt``
    nears 2 (k = 20), while the sampled-data law decays as ``exp(-k dt)`` at any gain: ``tune``
    must be able to pick it, with a gain the plain law cannot use."""
    _, grid = CLASSICAL["tuned_law"]
    assert set(grid["variant"]) == {"plain", "sampled"} and max(grid["gain"]) >= 160.0
    best, table = tune("tuned_law", env_id("cartpole"), "coarse", n_episodes=3)
    assert {row["variant"] for row in table} == {"plain", "sampled"}
    assert best["variant"] == "sampled" and best["gain"] >= 40.0
    plain_at_20 = next(r for r in table if r["variant"] == "plain" and r["gain"] == 20.0)
    assert plain_at_20["score"] < 0.5 < max(r["score"] for r in table)
