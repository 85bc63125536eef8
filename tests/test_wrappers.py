"""Tests of vnhc_gym.wrappers: ResidualAction (single env), ResidualVectorAction (vector env) and
ResidualPolicy.

The reference for every wrapped run is the same environment driven by hand: the base controller's
action (plus the residual, scaled and clipped, as documented) fed to an unwrapped environment with
the same seeds, with ``episode_start`` given to a stateful base where a new episode begins.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode

import vnhc_gym  # noqa: F401
from vnhc_gym.baselines import GeometricController, ObserverController, ZeroPolicy, make_classical
from vnhc_gym.evaluation import TEST_SEED, evaluate
from vnhc_gym.tasks import env_id, env_ids
from vnhc_gym.wrappers import ResidualAction, ResidualPolicy, ResidualVectorAction

ENVS = env_ids("v1")
USV = env_id("usv")
FLOCK = env_id("flocking")


def _short(e: str) -> str:
    return e.removeprefix("vnhc_gym/")


def _vec(env: str, n: int, **kwargs: Any) -> gym.vector.VectorEnv:
    return gym.make_vec(env, num_envs=n, vectorization_mode="vector_entry_point", **kwargs)


class _Linear:
    """A deterministic 'agent' that depends on its whole input: ``tanh(W obs)`` rounded to 1e-4 (so a
    single observation and a batch give the same bits whatever the matrix product's summation order)."""

    def __init__(self, in_dim: int, out_dim: int, seed: int = 0) -> None:
        self.w = np.random.default_rng(seed).normal(0, 1.0, (in_dim, out_dim))
        self.in_dim = in_dim

    def predict(self, obs: Any, state: Any = None, episode_start: Any = None, deterministic: bool = True):
        o = np.asarray(obs, dtype=np.float64)
        assert o.shape[-1] == self.in_dim
        return np.round(np.tanh(3 * o @ self.w), 4).astype(np.float32), state


class _Record(gym.Wrapper):
    """Records the actions the inner environment receives."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self.actions: list[np.ndarray] = []

    def step(self, action: Any):
        self.actions.append(np.array(action, copy=True))
        return self.env.step(action)


# --------------------------------------------------------------------------- single environment
def _run_single(env: gym.Env, act: Any, n: int = 60, seed: int = TEST_SEED) -> tuple[np.ndarray, list, list]:
    obs, info = env.reset(seed=seed)
    observations, rewards, infos = [obs], [], [info]
    for t in range(n):
        obs, r, term, trunc, info = env.step(act(obs, t))
        observations.append(obs)
        rewards.append(r)
        infos.append(info)
        if term or trunc:
            break
    return np.stack(observations), rewards, infos


@pytest.mark.parametrize("scenario", ["nominal", "noisy"])
@pytest.mark.parametrize("env", ENVS, ids=_short)
def test_zero_residual_is_the_base_law(env: str, scenario: str, assert_same: Any) -> None:
    plain = gym.make(env, scenario=scenario)
    law = GeometricController(plain)
    obs_a, rew_a, info_a = _run_single(plain, lambda o, t: law.predict(o)[0])
    wrapped = ResidualAction(gym.make(env, scenario=scenario))
    assert wrapped.observation_space == plain.observation_space and wrapped.action_space == plain.action_space
    zero = np.zeros(wrapped.action_space.shape, dtype=np.float32)
    obs_b, rew_b, info_b = _run_single(wrapped, lambda o, t: zero)
    assert_same(obs_a, obs_b)
    assert_same(rew_a, rew_b)
    for t, (ia, ib) in enumerate(zip(info_a[1:], info_b[1:], strict=True)):
        assert_same(ia["state"], ib["state"])
        assert_same(ia["force"], ib["force"])
        np.testing.assert_array_equal(ib["residual_action"], 0.0)
        # base_action is the law's action on the previous observation.
        np.testing.assert_array_equal(ib["base_action"], law.predict(obs_a[t])[0])
    plain.close()
    wrapped.close()


def test_zero_residual_on_a_stateful_base_is_that_base() -> None:
    """The observer keeps a state estimate: the wrapper restarts it at every reset."""
    plain = gym.make(FLOCK, scenario="noisy")
    observer = ObserverController(plain)
    runs = []
    for seed in (TEST_SEED, TEST_SEED + 1):
        runs.append(_run_single(plain, lambda o, t: observer.predict(o, episode_start=[t == 0])[0], seed=seed)[0])
    wrapped = ResidualAction(gym.make(FLOCK, scenario="noisy"), base="observer")
    assert isinstance(wrapped.base, ObserverController)
    zero = np.zeros(3, dtype=np.float32)
    for seed, ref in zip((TEST_SEED, TEST_SEED + 1), runs, strict=True):
        obs, _, _ = _run_single(wrapped, lambda o, t: zero, seed=seed)
        np.testing.assert_array_equal(obs, ref)
    plain.close()
    wrapped.close()


@pytest.mark.parametrize("env", ENVS, ids=_short)
def test_residual_is_scaled_clipped_and_added(env: str) -> None:
    rec = _Record(gym.make(env))
    w = ResidualAction(rec, scale=0.25)
    law = GeometricController(gym.make(env))
    task = w.unwrapped.task
    obs, _ = w.reset(seed=TEST_SEED)
    m = w.action_space.shape[0]
    for residual in (np.full(m, 3.0), np.full(m, -0.4), np.linspace(-1, 1, m)):
        base = law.predict(obs)[0].astype(np.float64)
        obs, _, _, _, info = w.step(residual.astype(np.float32))
        expected = np.clip(base + 0.25 * np.clip(residual, -1, 1), -1, 1)
        np.testing.assert_allclose(rec.actions[-1], expected, rtol=1e-6, atol=1e-7)
        np.testing.assert_allclose(info["force"], expected * task.force_bound, rtol=1e-6, atol=1e-6)
        np.testing.assert_allclose(info["residual_action"], 0.25 * np.clip(residual, -1, 1), rtol=1e-6)
        np.testing.assert_array_equal(info["base_action"], base.astype(np.float32))
        assert info["base_action"].dtype == np.float32 and info["residual_action"].dtype == np.float32
    w.close()


@pytest.mark.parametrize("env", ENVS, ids=_short)
def test_observe_base_appends_the_base_action(env: str) -> None:
    plain = gym.make(env)
    w = ResidualAction(gym.make(env), observe_base=True)
    law = GeometricController(plain)
    d, m = plain.observation_space.shape[0], plain.action_space.shape[0]
    space = w.observation_space
    assert space.shape == (d + m,) and space.dtype == np.float32
    np.testing.assert_array_equal(space.low, np.concatenate([plain.observation_space.low, -np.ones(m)]))
    np.testing.assert_array_equal(space.high, np.concatenate([plain.observation_space.high, np.ones(m)]))
    obs, _ = w.reset(seed=TEST_SEED)
    raw, _ = plain.reset(seed=TEST_SEED)
    rng = np.random.default_rng(0)
    for _ in range(10):
        assert obs.shape == (d + m,) and obs.dtype == np.float32 and space.contains(obs)
        np.testing.assert_array_equal(obs[:d], raw)
        np.testing.assert_array_equal(obs[d:], law.predict(raw)[0])
        a = rng.uniform(-1, 1, m).astype(np.float32)
        obs, _, _, _, info = w.step(a)
        raw, *_ = plain.step(np.clip(law.predict(raw)[0].astype(np.float64) + 0.2 * a.astype(np.float64), -1, 1)
                              .astype(np.float32))
    w.close()
    plain.close()


def test_space_and_argument_checks() -> None:
    with pytest.raises(TypeError, match="Box"):
        ResidualAction(gym.make("CartPole-v1"))  # Discrete actions
    with pytest.raises(TypeError, match=r"Box\(-1, 1\)"):
        ResidualAction(gym.make("Pendulum-v1"))  # Box(-2, 2)
    with pytest.raises(TypeError, match="predict"):
        ResidualAction(gym.make(USV), base=object())
    with pytest.raises(ValueError, match="scale"):
        ResidualAction(gym.make(USV), scale=1.5)
    with pytest.raises(ValueError, match="unknown classical baseline"):
        ResidualAction(gym.make(USV), base="pid")
    with pytest.raises(ValueError, match="scale"):
        ResidualVectorAction(_vec(USV, 2), scale=-0.1)
    # A custom base is used as given.
    env = gym.make(FLOCK)
    w = ResidualAction(env, base=ZeroPolicy(env), scale=0.5)
    w.reset(seed=0)
    _, _, _, _, info = w.step(np.ones(3, dtype=np.float32))
    np.testing.assert_array_equal(info["base_action"], 0.0)
    np.testing.assert_allclose(info["force"], 0.5 * env.unwrapped.task.force_bound)
    assert ResidualAction(gym.make(USV), gain=2.0).base.gain.tolist() == [2.0]


# --------------------------------------------------------------------------- vector environment
def _drive_vector(env: str, n: int, mode: AutoresetMode, base_name: str, steps: int, residual: Any,
                  **kwargs: Any) -> tuple[list, list]:
    """The reference: a plain vector env with the base driven by hand (episode starts as documented)."""
    venv = _vec(env, n, autoreset_mode=mode, **kwargs)
    base = make_classical(base_name, venv)
    obs, _ = venv.reset(seed=TEST_SEED)
    starts = np.ones(n, dtype=bool)
    pending = np.zeros(n, dtype=bool)
    observations, infos = [obs], []
    for t in range(steps):
        b, _ = base.predict(obs, episode_start=starts)
        r = np.asarray(residual(t, obs)).astype(np.float32).astype(np.float64)  # what an agent's float32 action is
        a = np.clip(b.astype(np.float64) + 0.2 * np.clip(r, -1, 1), -1, 1).astype(np.float32)
        base.applied(a)  # a stateful base predicts with what the environment received
        obs, _, term, trunc, info = venv.step(a)
        done = term | trunc
        if mode is AutoresetMode.SAME_STEP:
            starts = done
        else:  # NEXT_STEP: the rows done at the last step restart at this one
            starts, pending = pending, done
        observations.append(obs)
        infos.append(info)
    venv.close()
    return observations, infos


@pytest.mark.parametrize("mode", [AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP], ids=lambda m: m.value)
@pytest.mark.parametrize("base", ["law", "observer"])
@pytest.mark.parametrize("env", ENVS, ids=_short)
def test_vector_wrapper_equals_the_base_driven_by_hand(env: str, base: str, mode: AutoresetMode) -> None:
    """Across autoresets (episodes of 7 steps), with a zero and an observation-dependent residual."""
    n, steps = 3, 20
    kw = {"scenario": "noisy", "max_episode_steps": 7}
    for residual in (lambda t, o: np.zeros((n, 1)), lambda t, o: np.sin(t + np.arange(n))[:, None] * o[:, :1]):
        ref_obs, ref_infos = _drive_vector(env, n, mode, base, steps, residual, **kw)
        w = ResidualVectorAction(_vec(env, n, autoreset_mode=mode, **kw), base=base, scale=0.2)
        obs, _ = w.reset(seed=TEST_SEED)
        np.testing.assert_array_equal(obs, ref_obs[0])
        for t in range(steps):
            obs, _, _, _, info = w.step(np.broadcast_to(residual(t, obs), (n, w.single_action_space.shape[0]))
                                        .astype(np.float32))
            np.testing.assert_array_equal(obs, ref_obs[t + 1])
            np.testing.assert_array_equal(info["force"], ref_infos[t]["force"])
        w.close()


@pytest.mark.parametrize("variant", ["plain", "sampled"])
@pytest.mark.parametrize("env", ENVS, ids=_short)
def test_vector_observe_base_and_final_observations(env: str, variant: str) -> None:
    """SAME_STEP: the returned observation and every ``final_obs`` get the base law's action appended,
    of the base's own variant."""
    n = 4
    kw = {"autoreset_mode": AutoresetMode.SAME_STEP, "max_episode_steps": 5}
    w = ResidualVectorAction(_vec(env, n, **kw), base="tuned_law", gain=5.0, observe_base=True,
                             base_settings={"variant": variant})
    plain = _vec(env, n, **kw)
    law = GeometricController(plain, variant=variant)
    d, m = plain.single_observation_space.shape[0], plain.single_action_space.shape[0]
    assert w.single_observation_space.shape == (d + m,)
    assert w.observation_space.shape == (n, d + m)
    obs, _ = w.reset(seed=TEST_SEED)
    raw, _ = plain.reset(seed=TEST_SEED)
    finals = 0
    for _ in range(12):
        np.testing.assert_array_equal(obs[:, :d], raw)
        np.testing.assert_array_equal(obs[:, d:], law.predict(raw)[0])
        obs, _, _, _, info = w.step(np.zeros((n, m), dtype=np.float32))
        raw, _, _, _, raw_info = plain.step(law.predict(raw)[0])
        if "final_obs" in raw_info:
            np.testing.assert_array_equal(info["_final_obs"], raw_info["_final_obs"])
            for i in np.flatnonzero(raw_info["_final_obs"]):
                final = info["final_obs"][i]
                assert final.shape == (d + m,) and final.dtype == np.float32
                np.testing.assert_array_equal(final[:d], raw_info["final_obs"][i])
                np.testing.assert_array_equal(final[d:], law.predict(raw_info["final_obs"][i])[0])
                finals += 1
    assert finals == 2 * n  # every sub-env ended twice (steps 5 and 10)
    w.close()
    plain.close()


def test_vector_reset_mask_keeps_the_other_rows_base_actions() -> None:
    n = 3
    w = ResidualVectorAction(_vec(USV, n, autoreset_mode=AutoresetMode.DISABLED), observe_base=True)
    obs, _ = w.reset(seed=TEST_SEED)
    obs, *_ = w.step(np.zeros((n, 1), dtype=np.float32))
    before = obs[:, -1].copy()
    mask = np.array([False, True, False])
    obs2, _ = w.reset(options={"reset_mask": mask})
    law = GeometricController(w.env)
    np.testing.assert_array_equal(obs2[[0, 2], -1], before[[0, 2]])
    np.testing.assert_array_equal(obs2[1, -1], law.predict(obs2[1, :-1])[0][0])
    w.close()



@pytest.mark.parametrize("env", ENVS, ids=_short)
def test_a_filter_base_shows_the_observation_of_its_estimate(env: str) -> None:
    """With a base that keeps an estimate the agent sees ``(obs, belief, base action)``; without
    observation noise the Kalman filter's estimate is the observed state, so its belief is ``obs``
    (up to the float32 observation's rounding)."""
    plain = gym.make(env)
    w = ResidualAction(gym.make(env), base="kalman", observe_base=True)
    d, m = plain.observation_space.shape[0], plain.action_space.shape[0]
    space = w.observation_space
    assert space.shape == (2 * d + m,)
    np.testing.assert_array_equal(space.low[d:2 * d], plain.observation_space.low)
    obs, _ = w.reset(seed=TEST_SEED)
    rng = np.random.default_rng(0)
    for _ in range(10):
        assert space.contains(obs)
        scale = np.maximum(1.0, np.abs(obs[:d]))
        np.testing.assert_allclose(obs[d:2 * d] / scale, obs[:d] / scale, rtol=0, atol=2e-5)
        obs, *_ = w.step(rng.uniform(-1, 1, m).astype(np.float32))
    w.close()
    plain.close()


def test_vector_filter_base_belief_is_the_base_driven_by_hand() -> None:
    """Under noise the belief is the filter's own: the same filter driven by hand on the unwrapped
    vector environment gives the same three parts, and the belief is not the raw observation."""
    n = 3
    kw = {"scenario": "noisy", "autoreset_mode": AutoresetMode.DISABLED}
    w = ResidualVectorAction(_vec(FLOCK, n, **kw), base="kalman", observe_base=True, base_settings={"q": 1e-2})
    plain = _vec(FLOCK, n, **kw)
    ref = make_classical("kalman", plain, gain=5.0, q=1e-2)
    d, m = plain.single_observation_space.shape[0], plain.single_action_space.shape[0]
    assert w.observation_space.shape == (n, 2 * d + m)
    obs, _ = w.reset(seed=TEST_SEED)
    raw, _ = plain.reset(seed=TEST_SEED)
    start = np.ones(n, dtype=bool)
    for _ in range(8):
        a, _ = ref.predict(raw, episode_start=start)
        start[:] = False
        np.testing.assert_array_equal(obs[:, :d], raw)
        np.testing.assert_array_equal(obs[:, d:2 * d], ref.belief(raw).astype(np.float32))
        np.testing.assert_array_equal(obs[:, 2 * d:], a)
        assert np.abs(obs[:, d:2 * d] - raw).max() > 1e-3
        obs, *_ = w.step(np.zeros((n, m), dtype=np.float32))
        raw, *_ = plain.step(a)
    w.close()
    plain.close()


# --------------------------------------------------------------------------- ResidualPolicy
@pytest.mark.parametrize("observe_base", [False, True])
@pytest.mark.parametrize("env", ENVS, ids=_short)
def test_residual_policy_is_the_wrapped_envs_applied_action(env: str, observe_base: bool) -> None:
    rec = _Record(gym.make(env))
    w = ResidualAction(rec, scale=0.3, observe_base=observe_base)
    d, m = rec.observation_space.shape[0], rec.action_space.shape[0]
    agent = _Linear(d + (m if observe_base else 0), m)
    policy = ResidualPolicy(agent, GeometricController(gym.make(env)), scale=0.3, observe_base=observe_base)
    obs, _ = w.reset(seed=TEST_SEED)
    for _ in range(30):
        raw = obs[:d]
        mine, state = policy.predict(raw)
        assert state is None and mine.dtype == np.float32 and mine.shape == (m,)
        obs, *_ = w.step(agent.predict(obs)[0])
        np.testing.assert_array_equal(rec.actions[-1], mine)
    # Batched, it is row by row.
    batch = np.stack([w.reset(seed=TEST_SEED + i)[0][:d] for i in range(4)])
    np.testing.assert_array_equal(policy.predict(batch)[0], np.stack([policy.predict(o)[0] for o in batch]))
    w.close()


def test_residual_policy_on_a_filter_base_sees_what_the_wrapper_showed() -> None:
    """A trained residual agent on a Kalman base is run by `ResidualPolicy` on the plain environment:
    it must receive the same ``(obs, belief, base action)`` it was trained on."""
    rec = _Record(gym.make(FLOCK, scenario="noisy"))
    w = ResidualAction(rec, scale=0.3, base="kalman", observe_base=True)
    d, m = rec.observation_space.shape[0], rec.action_space.shape[0]
    agent = _Linear(2 * d + m, m)
    policy = ResidualPolicy(agent, make_classical("kalman", gym.make(FLOCK, scenario="noisy"), gain=5.0),
                            scale=0.3, observe_base=True)
    obs, _ = w.reset(seed=TEST_SEED)
    for t in range(20):
        mine, _ = policy.predict(obs[:d], episode_start=np.array([t == 0]))
        obs, *_ = w.step(agent.predict(obs)[0])
        np.testing.assert_array_equal(rec.actions[-1], mine)
    w.close()


def test_residual_policy_passes_episode_starts_to_a_stateful_base() -> None:
    """With a zero agent, the residual policy on the observer is the observer, episode for episode."""
    zero = ZeroPolicy(obs_dim=12, act_dim=3)

    def make(env: Any) -> ResidualPolicy:
        return ResidualPolicy(zero, ObserverController(env), name="residual-observer")

    a = evaluate(make, FLOCK, "noisy", n_episodes=3, seed=TEST_SEED, max_time=3.0)
    b = evaluate(ObserverController, FLOCK, "noisy", n_episodes=3, seed=TEST_SEED, max_time=3.0)
    assert a.policy == "residual-observer"
    np.testing.assert_array_equal(a.abs_phi, b.abs_phi)


def test_ppo_learns_on_the_single_residual_env() -> None:
    """RL Zoo's path: SB3 on gym.make + ResidualAction."""
    pytest.importorskip("stable_baselines3")
    from stable_baselines3 import PPO

    env = ResidualAction(gym.make(USV, max_episode_steps=50), observe_base=True)
    model = PPO("MlpPolicy", env, n_steps=64, batch_size=32, n_epochs=1, seed=0, device="cpu", verbose=0)
    model.learn(total_timesteps=128)
    obs, _ = env.reset(seed=0)
    action, _ = model.predict(obs, deterministic=True)
    assert action.shape == (1,)
    _, _, _, _, info = env.step(action)
    assert np.isfinite(info["abs_phi"])
    env.close()
