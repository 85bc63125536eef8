"""The extended Kalman filter baseline: its covariance against the discrete Riccati equation on a
linear system, its estimate against the raw observation under the scenario's own noise, and the
plain law where there is no noise."""

from __future__ import annotations

import types

import gymnasium as gym
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import sympy as sp
from scipy.linalg import solve_discrete_are

import vnhc_gym.tasks
from vnhc_gym.baselines import GeometricController
from vnhc_gym.baselines.kalman import (
    EKF,
    FilterNoise,
    InformedKalmanController,
    KalmanController,
    correct,
    predict,
    process_noise,
)
from vnhc_gym.mechanics import MechanicalSystem, VelocityConstraint, derive_law
from vnhc_gym.mechanics.printing import print_module

SLED = "vnhc_gym/SledCruise-v1"


def _oscillator(k: float) -> types.ModuleType:
    x, xd = sp.symbols("x xd", real=True)
    ks = sp.Symbol("k", positive=True)
    system = MechanicalSystem(name="osc", q=(x,), qd=(xd,), mass_matrix=sp.eye(1), control_forces=sp.Matrix([1]),
                              potential=ks * x**2 / 2, params={ks: k})
    module = types.ModuleType("osc")
    text = print_module(derive_law(system, VelocityConstraint(sp.Matrix([xd]))), "osc", "test")
    exec(compile(text, "osc", "exec"), module.__dict__)  # noqa: S102 - our own printed text
    return module


def test_covariance_converges_to_the_discrete_riccati_solution() -> None:
    """x'' = -k x, position measured with variance r: the filter's predicted covariance tends to the
    solution of the discrete algebraic Riccati equation of A (RK4's step matrix, by hand), H, Q, R."""
    k, dt, r, q = 4.0, 0.05, 0.02**2, 0.5
    osc = _oscillator(k)
    m = np.array([[0.0, 1.0], [-k, 0.0]]) * dt
    a = np.eye(2) + m + m @ m / 2 + m @ m @ m / 6 + m @ m @ m @ m / 24  # RK4 on a linear system
    h = np.array([[1.0, 0.0]])
    rng = np.random.default_rng(0)
    with jax.enable_x64(True):
        q_mat = np.asarray(process_noise(1, dt, q))
        x, cov = jnp.array([0.3, -0.2]), jnp.eye(2) * 0.1
        step = jax.jit(lambda x_, c_: predict(osc, dt, 1, (), x_, c_, jnp.asarray(osc.PARAM_DEFAULTS), jnp.zeros(1),
                                              q_mat))
        for _ in range(400):
            pred, prior = step(x, cov)
            z = np.array([rng.normal(0.0, np.sqrt(r))])
            x, cov = correct(pred, prior, pred[:1], jnp.asarray(h), z, r)
    np.testing.assert_allclose(prior, solve_discrete_are(a.T, h.T, q_mat, np.array([[r]])), rtol=1e-8)


def test_the_estimate_beats_the_raw_observation_under_the_scenarios_noise() -> None:
    env = gym.make(SLED, scenario="noisy")
    obs, info = env.reset(seed=5001)
    task = env.unwrapped.task
    ekf = KalmanController(env, gain=10.0, q=0.001)
    raw, est = [], []
    for t in range(200):
        action, _ = ekf.predict(obs)
        truth = task.controller_inputs(task.observation_of(info["state"][None], task.nominal[None]))[0][0]
        if t >= 20:  # past the filter's start
            raw.append(task.controller_inputs(obs[None].astype(np.float64))[0][0] - truth)
            est.append(ekf._x[0] - truth)
        ekf.applied(action)
        obs, _, terminated, truncated, info = env.step(action)
        assert not terminated
    rms_raw, rms_est = (np.sqrt(np.mean(np.square(e), axis=0))[3:] for e in (raw, est))
    assert np.all(rms_est < 0.5 * rms_raw), (rms_est, rms_raw)


@pytest.mark.parametrize("env_id", [SLED, "vnhc_gym/CartPoleBalance-v1", "vnhc_gym/SpacecraftPoint-v1"])
def test_without_noise_the_filter_is_the_plain_law(env_id: str) -> None:
    env = gym.make(env_id)
    obs, _ = env.reset(seed=3)
    ekf, law = KalmanController(env, gain=5.0, q=0.01), GeometricController(env, gain=5.0)
    for _ in range(30):
        a, _ = ekf.predict(obs)
        b, _ = law.predict(obs)
        np.testing.assert_allclose(a, b, atol=1e-4)
        ekf.applied(a)
        obs, *_ = env.step(a)


def test_a_flock_of_any_size_is_filtered() -> None:
    """The flock's model is a fleet of its printed unit for any size, so the filter runs on 6 agents."""
    env = gym.make("vnhc_gym/FlockingAlign-v1", n_agents=6)
    controller = KalmanController(env)
    obs, _ = env.reset(seed=0)
    for _ in range(3):
        action, _ = controller.predict(obs)
        assert action.shape == env.action_space.shape and np.all(np.isfinite(action))
        obs, *_ = env.step(action)


@pytest.mark.parametrize("name", sorted(vnhc_gym.tasks.shipped_tasks()))
def test_observation_of_inverts_the_read_back(name: str) -> None:
    """The filter's measurement model: the observation of the state read back from an observation is
    that observation (every entry the controller's frame holds; the others are NaN)."""
    env = gym.make(vnhc_gym.tasks.env_id(name))
    obs, _ = env.reset(seed=2)
    rng = np.random.default_rng(0)
    for _ in range(5):
        obs, *_ = env.step(rng.uniform(-1, 1, env.action_space.shape).astype(np.float32))
    task = env.unwrapped.task
    states, params = task.controller_inputs(obs[None].astype(np.float64))
    back = task.observation_of(states, params)[0]
    seen = np.isfinite(back)
    assert seen.sum() >= task.obs_dim - 2
    np.testing.assert_allclose(back[seen], obs[seen], atol=1e-6)


def test_the_boats_velocity_through_the_water_moves_without_the_current() -> None:
    """The fact the boat's filter rests on (`USVTask.parameter_drift`): ``w = qd - n n^T C`` with ``n =
    (sin theta, -cos theta)`` obeys ``m dw/dt = u n`` in any current (here a random field, by hand
    from the model's acceleration and ``dC/dt = J qd``), and a step of the current along the drift
    the task declares leaves ``w`` where it was."""
    env = gym.make("vnhc_gym/USVStream-v1")
    _, info = env.reset(seed=4)
    task, model = env.unwrapped.task, env.unwrapped.task.model
    m = info["params"][model.param_names.index("m")]
    rng = np.random.default_rng(1)
    for _ in range(5):
        s = np.concatenate([rng.uniform(-5, 5, 2), rng.uniform(-np.pi, np.pi, 1), rng.uniform(-2, 2, 3)])
        u = rng.uniform(-50, 50)
        acc = model.acceleration(s, np.array([u]), info["params"])
        c1, c2, j11, j12, j21, j22 = model.outputs(s, info["params"])[:6]
        th, thd, v = s[2], s[5], s[3:5]
        n, n_dot = np.array([np.sin(th), -np.cos(th)]), thd * np.array([np.cos(th), np.sin(th)])
        c, c_dot = np.array([c1, c2]), np.array([[j11, j12], [j21, j22]]) @ v
        v_normal_dot = n_dot * (n @ c) + n * (n_dot @ c) + n * (n @ c_dot)
        np.testing.assert_allclose(m * (acc[:2] - v_normal_dot), u * n, atol=1e-9)

    states = np.column_stack([np.zeros((4, 2)), rng.uniform(-np.pi, np.pi, 4), rng.uniform(-2, 2, (4, 3))])
    names = task.controller_model().param_names
    params = np.tile(task.controller_model().default_params, (4, 1))
    cols = [names.index(p) for p in task.filtered_params]
    params[:, cols] = rng.uniform(-1, 1, (4, len(cols)))
    drift = task.parameter_drift(states, params)
    step = rng.normal(size=(4, len(cols)))

    def through_the_water(s: np.ndarray, p: np.ndarray) -> np.ndarray:
        n = np.stack([np.sin(s[:, 2]), -np.cos(s[:, 2])], axis=1)
        c = p[:, [names.index("c_c1"), names.index("c_c2")]]
        return s[:, 3:5] - n * np.sum(n * c, axis=1, keepdims=True)

    moved_params = params.copy()
    moved_params[:, cols] += step
    moved = states + np.einsum("bik,bk->bi", drift, step)
    np.testing.assert_allclose(through_the_water(moved, moved_params), through_the_water(states, params), atol=1e-12)
    np.testing.assert_array_equal(moved[:, [0, 1, 2, 5]], states[:, [0, 1, 2, 5]])


def test_the_boats_filter_sees_phi_far_better_than_its_observation() -> None:
    """Under the noisy scenario's noise the filter's ``phi`` is several times closer to the truth than
    the observed ``phi``: a filter that let the current drift without the velocity it carries stays
    about three times closer only."""
    env = gym.make("vnhc_gym/USVStream-v1", scenario="noisy")
    obs, info = env.reset(seed=5001)
    task = env.unwrapped.task
    ekf = KalmanController(env, gain=80.0, q=1e-4, variant="sampled")
    model = task.controller_model()
    raw, est = [], []
    for t in range(200):
        action, _ = ekf.predict(obs)
        if t >= 20:
            estimate = model.phi(ekf._x[:, :6], ekf._params(ekf._x, ekf._base))[0, 0]
            raw.append(2.0 * obs[9] - info["phi"][0])  # the observation holds phi / 2
            est.append(estimate - info["phi"][0])
        obs, _, terminated, truncated, info = env.step(action)
        assert not terminated
    rms_raw, rms_est = np.sqrt(np.mean(np.square(raw))), np.sqrt(np.mean(np.square(est)))
    assert rms_est < 0.2 * rms_raw, (rms_est, rms_raw)


# ---------------------------------------------------------------------------------------------
# The informed filter (a headroom reference): told the true parameters, never the state


@pytest.mark.parametrize(("env_id", "scenario"), [("vnhc_gym/CartPoleBalance-v1", "noisy"),
                                                  ("vnhc_gym/USVStream-v1", "nominal")])
def test_told_what_the_filter_already_knows_the_informed_filter_acts_as_it(env_id: str, scenario: str) -> None:
    """The noisy scenario leaves the parameters nominal, and without noise the boat's observation gives
    its local current exactly: told nothing new, the informed filter acts as the filter."""
    envs = [gym.make(env_id, scenario=scenario) for _ in range(2)]
    ekf = KalmanController(envs[0], gain=20.0, q=1e-4)
    told = InformedKalmanController(envs[1], gain=20.0, q=1e-4)
    obs = [e.reset(seed=7)[0] for e in envs]
    for _ in range(40):
        a, _ = ekf.predict(obs[0])
        b, _ = told.predict(obs[1])
        np.testing.assert_allclose(b, a, atol=1e-6)
        obs = [e.step(x)[0] for e, x in ((envs[0], a), (envs[1], b))]


def test_the_informed_filter_runs_the_episodes_true_parameters() -> None:
    """Under mismatch its model's parameters are the episode's true ones, which differ from the nominal
    ones the filter is given; and it reads the environment's rows, so a batch of another size is an
    error naming the rows."""
    env = gym.make("vnhc_gym/CartPoleBalance-v1", scenario="mismatch")
    obs, info = env.reset(seed=2)
    told = InformedKalmanController(env, gain=5.0)
    told.predict(obs)
    assert told._base is not None
    np.testing.assert_allclose(told._base[0], info["params"], rtol=1e-12)
    _, nominal = env.unwrapped.task.controller_inputs(obs[None, :])
    assert not np.allclose(nominal[0], info["params"])
    with pytest.raises(ValueError, match="all 1 rows"):
        told.predict(np.stack([obs, obs, obs]))


def test_the_boats_informed_filter_knows_the_current_at_the_boat() -> None:
    """The law runs on the true field's value and gradient at the boat's true position (the random
    field's outputs there), though the observations it reads are noisy: the correction never moves
    the told parameters."""
    env = gym.make("vnhc_gym/USVStream-v1", scenario="noisy")
    obs, _ = env.reset(seed=4)
    told = InformedKalmanController(env, gain=20.0, q=1e-4)
    for _ in range(5):
        action, _ = told.predict(obs)
        obs, *_ = env.step(action)
    told.predict(obs)
    task = env.unwrapped.task
    batch = env.unwrapped.batch
    names = task.controller_model().param_names
    aux = task.model.outputs(batch.buf.state, batch.buf.params_true)[0]
    want = dict(zip(("c_c1", "c_c2", "c_j11", "c_j12", "c_j21", "c_j22"), aux, strict=False))
    assert told._x is not None and told._base is not None
    used = told._params(told._x, told._base)[0]  # what the law runs on: the filter's, if it moved them
    for name, value in want.items():
        assert used[names.index(name)] == pytest.approx(value, abs=1e-12)


def test_under_mismatch_the_informed_filter_reads_the_boats_true_phi() -> None:
    """The boat observes with its chart (the nominal current), while the true current drives it: with
    the measurement computed the environment's way, the informed filter's ``phi`` (no noise in the
    mismatch scenario) is the environment's true ``phi``, though the observed one is not."""
    env = gym.make("vnhc_gym/USVStream-v1", scenario="mismatch")
    obs, info = env.reset(seed=11)
    told = InformedKalmanController(env, gain=20.0, q=1e-4)
    model = env.unwrapped.task.controller_model()
    gaps = []
    for _ in range(30):
        action, _ = told.predict(obs)
        assert told._x is not None and told._base is not None
        estimate = model.phi(told._x[:, :6], told._params(told._x, told._base))[0, 0]
        assert estimate == pytest.approx(info["phi"][0], abs=1e-4)
        gaps.append(abs(2.0 * obs[9] - info["phi"][0]))  # the observation's phi, with the chart's current
        obs, _, terminated, _, info = env.step(action)
        assert not terminated
    assert max(gaps) > 1e-2  # the chart differs from the truth, so reading phi off the observation would not do


@pytest.mark.parametrize("env_id", ["vnhc_gym/USVStream-v1", SLED, "vnhc_gym/CartPoleBalance-v1"],
                         ids=lambda e: e.removeprefix("vnhc_gym/"))
def test_the_pure_filter_estimates_what_the_controller_estimates(env_id: str) -> None:
    """`EKF` (one episode, exact Jacobians, vmapped) against `KalmanController` (numpy, central
    differences) on the same noisy observations and applied forces: the boat (filtered current,
    moving frame, unmeasured entries), the sled (moving frame), the cart-pole (neither)."""
    venv = gym.make_vec(env_id, num_envs=3, vectorization_mode="vector_entry_point", scenario="noisy")
    ctrl = KalmanController(venv, gain=10.0, q=0.01)
    task = ctrl.task
    ekf = EKF.of(task)
    noise = FilterNoise(float(task.config.dt), float(task.config.obs_noise), 0.01, ctrl.q_params)
    obs, _ = venv.reset(seed=7)
    f, u = None, None
    with jax.enable_x64(True):
        start = jax.jit(jax.vmap(ekf.start, in_axes=(0, None, None, None)))
        update = jax.jit(jax.vmap(ekf.update, in_axes=(0, 0, 0, None, None, None)))
        for _ in range(30):
            action, _ = ctrl.predict(obs)
            o = np.asarray(obs, dtype=np.float64)
            f = (start(o, task.nominal, task.args, noise.sigma) if f is None
                 else update(f, o, u, task.nominal, task.args, noise))
            x, p = jax.vmap(ekf.estimate)(f)
            want_x, want_p = ctrl._estimate
            np.testing.assert_allclose(np.asarray(x), want_x, rtol=1e-7, atol=1e-8)
            np.testing.assert_allclose(np.asarray(p), want_p, rtol=1e-7, atol=1e-8)
            u = np.asarray(action, dtype=np.float64) * ctrl.force_bound
            obs, _, terminated, truncated, _ = venv.step(action)
            assert not np.any(terminated | truncated)
    assert np.abs(np.asarray(x) - task.controller_inputs(np.asarray(obs))[0]).max() > 0  # not the raw read-back


def test_filters_of_one_task_are_equal_and_share_their_programs() -> None:
    """Two controllers of the sled (other gains, other noise settings) run one filter's compiled code."""
    env = gym.make(SLED, scenario="noisy")
    a, b = KalmanController(env, gain=5.0, q=1e-4), KalmanController(env, gain=80.0, q=1e-2, variant="sampled")
    assert a.ekf == b.ekf and hash(a.ekf) == hash(b.ekf)
    with pytest.raises(ValueError, match="q"):
        KalmanController(env, q=-1.0)
