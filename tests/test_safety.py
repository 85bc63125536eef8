"""Tests of the safety filter for declared velocity limits (vnhc_gym.baselines.safety).

Expected values come from facts that do not depend on the code under test: the environments' own
terminations and true states (``info``), the bounds the tasks declare, the barrier condition
``dh/dt >= -rate h`` evaluated with the model's accelerations, a half-space projection worked by
hand, and the seeds the tuning may read.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
import pytest

import vnhc_gym  # noqa: F401  (registers the environments)
import vnhc_gym.evaluation
import vnhc_gym.evaluation.protocol
from vnhc_gym.baselines import (
    CLASSICAL,
    GeometricController,
    ObserverController,
    SafeLaw,
    SafetyFilter,
    ZeroPolicy,
    make_classical,
    tune,
)
from vnhc_gym.baselines.safety import project_box, solve_qp, velocity_limits
from vnhc_gym.baselines.tuning import applicable
from vnhc_gym.evaluation import TEST_SEED, evaluate
from vnhc_gym.tasks import env_id

USV, SLED, CARTPOLE = env_id("usv"), env_id("sled"), env_id("cartpole")
FLOCK, SPACECRAFT = env_id("flocking"), env_id("spacecraft")


def _vec(env: str, n: int, **kwargs: Any) -> gym.vector.VectorEnv:
    return gym.make_vec(env, num_envs=n, vectorization_mode="vector_entry_point", **kwargs)


class FullPush(ZeroPolicy):
    """Action 1 on every control, every step; records what a filter forwards to it."""

    name = "full_push"

    def __init__(self, env: Any) -> None:
        super().__init__(env)
        self.starts: list[Any] = []
        self.told: list[np.ndarray] = []

    def predict(self, observation: Any, state: Any = None, episode_start: Any = None,
                deterministic: bool = True) -> tuple[np.ndarray, Any]:
        self.starts.append(None if episode_start is None else np.asarray(episode_start).copy())
        return super().predict(observation, state, episode_start, deterministic)

    def act(self, obs: np.ndarray) -> np.ndarray:
        return np.ones((obs.shape[0], self.act_dim))

    def applied(self, action: Any) -> None:
        self.told.append(np.asarray(action, dtype=np.float64).copy())


def _turn_rate_limit(env: str) -> tuple[int, float]:
    task = gym.make(env).unwrapped.task
    ((_, index, bound),) = [lim for lim in task.limits if lim[0] == "turn_rate_exceeded"]
    return index, bound


def _run(env: str, policy_of: Any, n: int = 4, steps: int = 400) -> tuple[np.ndarray, list[Any]]:
    """Largest |turn rate| of each episode (true state) and the termination reasons seen."""
    index, _ = _turn_rate_limit(env)
    venv = _vec(env, n)
    policy = policy_of(venv)
    obs, info = venv.reset(seed=TEST_SEED)
    peak = np.abs(info["state"][:, index])
    reasons: list[Any] = []
    done = np.zeros(n, dtype=bool)
    for _ in range(steps):
        a, _ = policy.predict(obs)
        obs, _, term, trunc, info = venv.step(a)
        live = ~done
        peak[live] = np.maximum(peak[live], np.abs(info["state"][live, index]))
        reasons += [info["termination_reason"][i] for i in np.flatnonzero(term & live)]
        done |= term | trunc
        if done.all():
            break
    venv.close()
    return peak, reasons


# --------------------------------------------------------------------------- the limits it reads
@pytest.mark.parametrize("task", ["usv", "sled", "cartpole"])
def test_limited_velocities_are_the_controller_states_velocities(task: str) -> None:
    """The filter reads the limited entries from the controller's states: they must be the
    environment's own velocities (true state in ``info``), up to the observation's rounding."""
    env = env_id(task)
    venv = _vec(env, 8)
    obs, info = venv.reset(seed=TEST_SEED)
    rng = np.random.default_rng(0)
    for _ in range(5):
        obs, _, _, _, info = venv.step(rng.uniform(-0.5, 0.5, venv.action_space.shape).astype(np.float32))
    t = venv.unwrapped.task
    lims = velocity_limits(t)
    declared = [(reason, i, b) for reason, i, b in t.limits if i >= t.model.n]
    assert len(lims) == len(declared) >= 1
    states, _ = t.controller_inputs(np.asarray(obs, dtype=np.float64))
    for (reason, k, bound), (reason2, i, bound2) in zip(lims, declared, strict=True):
        assert (reason, bound) == (reason2, bound2)
        np.testing.assert_allclose(states[:, t.controller_model().n + k], info["state"][:, i], rtol=1e-5, atol=1e-5)
    venv.close()


# --------------------------------------------------------------------------- far from the limits
@pytest.mark.parametrize("env", [USV, CARTPOLE])
def test_the_base_force_is_unchanged_far_from_every_limit(env: str) -> None:
    venv = _vec(env, 8)
    law = GeometricController(venv, gain=5.0)
    safe = SafetyFilter(GeometricController(venv, gain=5.0), venv, margin=0.2, rate=10.0)
    t = venv.unwrapped.task
    obs, info = venv.reset(seed=TEST_SEED)
    peak = 0.0
    for _ in range(100):
        a_law, _ = law.predict(obs)
        a_safe, _ = safe.predict(obs)
        np.testing.assert_array_equal(a_safe, a_law)
        obs, _, term, _, info = venv.step(a_law)
        assert not term.any()
        peak = max(peak, max(float(np.max(np.abs(info["state"][:, i]) / b)) for _, i, b in t.limits if i >= t.model.n))
    # The precondition of the test: every limited velocity stayed below 40 % of its bound (half of
    # the 80 % the barrier allows).
    assert peak < 0.4
    assert safe.n_filtered == 0 and safe.n_rows == 800
    venv.close()


# --------------------------------------------------------------------------- a base that crosses a limit
@pytest.mark.parametrize("env", [USV, SLED])
def test_a_full_push_spins_past_the_limit_unless_filtered(env: str) -> None:
    """Full force every step spins the boat (one control: the closed form) and the sled (two
    controls: the programme) past their turn-rate limit; filtered, neither crosses it."""
    if env == SLED:
        pytest.importorskip("osqp")
    _, bound = _turn_rate_limit(env)
    peak, reasons = _run(env, FullPush, steps=100)
    assert "turn_rate_exceeded" in reasons and np.max(peak) > bound
    margin = 0.2
    peak, reasons = _run(env, lambda v: SafetyFilter(FullPush(v), v, margin=margin, rate=10.0))
    assert reasons == []
    assert np.all(peak <= bound)
    # It gets where the base pushes it, to the margin's edge, and not much past it.
    assert np.all(peak > 0.9 * (1 - margin) * bound) and np.all(peak < (1 - margin / 2) * bound)


def test_the_filtered_force_meets_the_barrier_condition() -> None:
    """``dh/dt >= -rate h`` with the model's accelerations at the filtered force, wherever the
    force bound allows it (and the hardest braking where it does not)."""
    venv = _vec(USV, 16)
    obs, _ = venv.reset(seed=TEST_SEED)
    margin, rate = 0.3, 5.0
    safe = SafetyFilter(FullPush(venv), venv, margin=margin, rate=rate)
    t = venv.unwrapped.task
    model = t.controller_model()
    (_, k, bound), = velocity_limits(t)
    c = (1 - margin) * bound
    checked = 0
    for _ in range(60):
        a, _ = safe.predict(obs)
        states, params = t.controller_inputs(np.asarray(obs, dtype=np.float64))
        v = states[:, model.n + k]
        h = c * c - v * v
        u = np.asarray(a, dtype=np.float64) * t.force_bound
        qdd = model.acceleration(states, u, params)
        hdot = -2.0 * v * qdd[:, k]
        at_bound = np.abs(np.asarray(a)[:, 0]) >= 1.0 - 1e-6
        ok = hdot >= -rate * h - 1e-6 * (1.0 + np.abs(rate * h))
        assert np.all(ok | at_bound)
        checked += int(np.sum(~at_bound))
        obs, _, term, _, _ = venv.step(a)
        assert not term.any()
    assert checked > 100  # the condition bound (the filter acted) on many rows, not only at the force bound
    venv.close()


# --------------------------------------------------------------------------- the closed form and the programme
def test_the_closed_form_is_the_half_space_projection_worked_by_hand() -> None:
    # 2 a <= 1 from a = 0.8: a = 0.5.  -a <= 0.25 from a = -0.9: a = -0.25.  Already inside: unchanged.
    a, conflict = project_box(np.array([0.8, -0.9, 0.1]), np.array([[2.0], [-1.0], [2.0]]),
                              np.array([[1.0], [0.25], [1.0]]))
    np.testing.assert_allclose(a, [0.5, -0.25, 0.1])
    assert not conflict.any()
    # A barrier beyond the force bound: the nearest action in [-1, 1] (the hardest braking).
    a, _ = project_box(np.array([0.0]), np.array([[-1.0]]), np.array([[-3.0]]))
    np.testing.assert_allclose(a, [1.0])


def test_the_closed_form_equals_the_quadratic_programme_for_one_control() -> None:
    pytest.importorskip("osqp")
    rng = np.random.default_rng(1)
    n_rows, n_lim = 200, 2
    a0 = rng.uniform(-1.0, 1.0, n_rows)
    rows = rng.normal(size=(n_rows, n_lim))
    rhs = rng.normal(scale=0.5, size=(n_rows, n_lim))
    closed, conflict = project_box(a0, rows, rhs)
    qp, solved = solve_qp(a0[:, None], rows[:, :, None], rhs, box=True)
    feasible = solved & ~conflict
    assert feasible.sum() > 100 and (~solved).sum() > 5  # both kinds of rows occur
    np.testing.assert_allclose(closed[feasible], qp[feasible, 0], atol=1e-7)
    # Where the programme is infeasible the closed form says why: conflicting barriers, or the
    # interval they leave lies outside the force bound.
    with np.errstate(divide="ignore"):
        edge = rhs / rows
    lower = np.where(rows < 0, edge, -np.inf).max(axis=1)
    upper = np.where(rows > 0, edge, np.inf).min(axis=1)
    empty = (lower > upper) | (lower > 1.0) | (upper < -1.0)
    np.testing.assert_array_equal(~solved, empty)


# --------------------------------------------------------------------------- a stateful base
def test_episode_starts_and_the_applied_force_reach_the_base() -> None:
    venv = _vec(USV, 4)
    base = FullPush(venv)
    safe = SafetyFilter(base, venv)
    obs, _ = venv.reset(seed=TEST_SEED)
    starts = np.array([True, False, True, False])
    for step in range(20):
        a, _ = safe.predict(obs, episode_start=starts if step == 0 else np.zeros(4, dtype=bool))
        obs, *_ = venv.step(a)
        np.testing.assert_array_equal(base.told[-1], np.asarray(a, dtype=np.float64))
    np.testing.assert_array_equal(base.starts[0], starts)
    assert safe.n_filtered > 0 and np.any(base.told[-1] < 1.0)  # told the filtered force, not its own
    venv.close()


def test_an_observer_base_predicts_with_the_filtered_force() -> None:
    venv = _vec(USV, 4, scenario="noisy")
    observer = ObserverController(venv, gain=5.0, alpha=0.1)
    safe = SafetyFilter(observer, venv, margin=0.2, rate=10.0)
    obs, _ = venv.reset(seed=TEST_SEED)
    for _ in range(10):
        a, _ = safe.predict(obs)
        assert observer._u is not None
        np.testing.assert_array_equal(observer._u, np.asarray(a, dtype=np.float64) * venv.unwrapped.task.force_bound)
        obs, *_ = venv.step(a)
    venv.close()


# --------------------------------------------------------------------------- tasks without velocity limits
@pytest.mark.parametrize("env", [FLOCK, SPACECRAFT])
def test_a_task_without_velocity_limits_gets_the_base_and_is_not_tuned(env: str,
                                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    """The flock has no limits, the spacecraft only one on a position (its pitch): the filter
    has nothing to keep, ``safe_law`` is its base law, and ``tune`` skips it without an episode."""
    task = gym.make(env).unwrapped.task
    assert all(i < task.model.n for _, i, _ in task.limits)
    assert not applicable("safe_law", env) and applicable("tuned_law", env)
    venv = _vec(env, 4)
    obs, _ = venv.reset(seed=TEST_SEED)
    safe = make_classical("safe_law", venv, gain=20.0, variant="sampled", margin=0.5, rate=5.0)
    law = GeometricController(venv, gain=20.0, variant="sampled")
    assert safe.limits == ()
    for _ in range(5):
        a, _ = safe.predict(obs)
        np.testing.assert_array_equal(a, law.predict(obs)[0])
        obs, *_ = venv.step(a)
    venv.close()
    calls: list[Any] = []

    def recording(*args: Any, **kwargs: Any) -> Any:
        calls.append(args)
        return evaluate(*args, **kwargs)

    monkeypatch.setattr(vnhc_gym.evaluation, "evaluate", recording)
    monkeypatch.setattr(vnhc_gym.evaluation.protocol, "evaluate", recording)
    assert tune("safe_law", env, "nominal", n_episodes=2) == ({}, [])
    assert calls == []


# --------------------------------------------------------------------------- the candidate
def test_safe_law_is_a_classical_candidate_of_the_law_family() -> None:
    cls, grid = CLASSICAL["safe_law"]
    assert cls is SafeLaw
    assert set(grid["variant"]) == {"plain", "sampled"} and max(grid["gain"]) >= 160.0
    assert len(grid["margin"]) >= 2 and len(grid["rate"]) >= 2
    env = gym.make(USV)
    pol = make_classical("safe_law", env, gain=80.0, variant="sampled", margin=0.5, rate=5.0)
    assert pol.name == "safe_law" and isinstance(pol.base, GeometricController)
    assert pol.base.variant == "sampled" and pol.base.gain.tolist() == [80.0]
    for bad in ({"margin": 1.0}, {"margin": -0.1}, {"rate": 0.0}, {"rate": float("nan")}):
        with pytest.raises(ValueError):
            make_classical("safe_law", env, **bad)
    with pytest.raises(TypeError, match="predict"):
        SafetyFilter(object(), env)
    env.close()


def test_the_filtered_law_finishes_the_kicked_boats_episodes_the_law_loses() -> None:
    """On the boat's ``disturbance`` episodes the sampled law at a high gain spins some boats past
    their turn rate; through the filter every episode reaches the time limit."""
    kwargs = {"n_episodes": 10, "seed": TEST_SEED}
    law = evaluate(lambda e: GeometricController(e, gain=80.0, variant="sampled"), USV, "disturbance", **kwargs)
    safe = evaluate(lambda e: SafeLaw(e, gain=80.0, variant="sampled"), USV, "disturbance", **kwargs)
    assert law.metrics["success"].mean() < 1.0
    assert safe.metrics["success"].mean() == 1.0
    assert safe.metrics["score"].mean() > law.metrics["score"].mean()
