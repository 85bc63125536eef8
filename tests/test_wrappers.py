"""Tests of vnhc_gym.wrappers.ResidualAction."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import vnhc_gym  # noqa: F401
from vnhc_gym.baselines import GeometricController, ZeroPolicy
from vnhc_gym.evaluation import evaluate
from vnhc_gym.wrappers import ResidualAction, ResidualPolicy

FLOCK = "vnhc_gym/FlockingAlign-v0"
USV = "vnhc_gym/USVStream-v0"


def _run(env: gym.Env, act, n: int = 80, seed: int = 0) -> tuple[np.ndarray, np.ndarray, list[dict]]:
    obs, _ = env.reset(seed=seed)
    observations, rewards, infos = [obs], [], []
    for _ in range(n):
        obs, r, term, trunc, info = env.step(act(obs))
        observations.append(obs)
        rewards.append(r)
        infos.append(info)
        if term or trunc:
            break
    return np.stack(observations), np.array(rewards), infos


@pytest.mark.parametrize("env_id", [FLOCK, USV])
@pytest.mark.parametrize("scenario", ["nominal", "noisy"])
def test_zero_residual_equals_base_policy_exactly(env_id: str, scenario: str) -> None:
    base_env = gym.make(env_id, scenario=scenario, disable_env_checker=True)
    base = GeometricController(base_env)
    obs_a, rew_a, info_a = _run(base_env, lambda o: base.predict(o)[0])
    wrapped = ResidualAction(gym.make(env_id, scenario=scenario, disable_env_checker=True))
    zero = np.zeros(wrapped.action_space.shape, dtype=np.float32)
    obs_b, rew_b, info_b = _run(wrapped, lambda o: zero)
    np.testing.assert_array_equal(obs_a, obs_b)
    np.testing.assert_array_equal(rew_a, rew_b)
    for ia, ib in zip(info_a, info_b, strict=True):
        np.testing.assert_array_equal(ia["state"], ib["state"])
        np.testing.assert_array_equal(ib["residual_action"], 0.0)
    # info shows the parts: base_action is what the base policy says for the previous observation.
    np.testing.assert_array_equal(info_b[0]["base_action"], base.predict(obs_a[0])[0])


def test_residual_is_added_scaled_and_clipped() -> None:
    env = ResidualAction(gym.make(USV, disable_env_checker=True), scale=0.25)
    obs, _ = env.reset(seed=1)
    base_a = env.base.predict(obs)[0]
    applied = env.action(np.array([3.0], dtype=np.float32))  # clipped to 1 first
    np.testing.assert_allclose(applied, np.clip(base_a + 0.25, -1, 1), rtol=1e-6)
    _, _, _, _, info = env.step(np.array([-0.4], dtype=np.float32))
    np.testing.assert_allclose(info["residual_action"], [-0.1], rtol=1e-6)
    assert info["base_action"].dtype == np.float32


def test_base_is_reset_and_custom_base_used() -> None:
    class Base(ZeroPolicy):
        resets = 0

        def reset(self) -> None:
            Base.resets += 1

    env = gym.make(FLOCK, disable_env_checker=True)
    w = ResidualAction(env, base=Base(env), scale=0.5)
    w.reset(seed=0)
    w.reset(seed=1)
    assert Base.resets == 2
    _, _, _, _, info = w.step(np.ones(3, dtype=np.float32))
    np.testing.assert_array_equal(info["base_action"], 0.0)
    np.testing.assert_allclose(info["force"], 0.5 * 250.0)


def test_space_checks_raise_type_error() -> None:
    with pytest.raises(TypeError, match="Box"):
        ResidualAction(gym.make("CartPole-v1"))  # Discrete actions
    with pytest.raises(TypeError, match=r"Box\(-1, 1\)"):
        ResidualAction(gym.make("Pendulum-v1"))  # Box(-2, 2)
    with pytest.raises(TypeError, match="predict"):
        ResidualAction(gym.make(USV, disable_env_checker=True), base=object())
    with pytest.raises(TypeError, match="task"):
        ResidualAction(gym.make("MountainCarContinuous-v0"), continuous=True)


def test_continuous_mode_uses_true_state_so_noise_does_not_matter() -> None:
    trajs = {}
    for scenario in ("nominal", "noisy"):
        w = ResidualAction(gym.make(USV, scenario=scenario, disable_env_checker=True), continuous=True)
        assert w.unwrapped.task.feedback == "continuous"
        _, _, infos = _run(w, lambda o: np.zeros(1, dtype=np.float32), n=100, seed=5)
        trajs[scenario] = np.array([i["abs_phi"] for i in infos])
        assert "base_action" in infos[0] and "residual_action" in infos[0]
        w.close()
        assert w.unwrapped.task.feedback == "open"
    np.testing.assert_array_equal(trajs["nominal"], trajs["noisy"])
    # The in-loop law makes phi decay like exp(-t): 5 s -> factor e^-5.
    assert trajs["nominal"][-1] < 0.02 * trajs["nominal"][0]


def test_residual_policy_matches_wrapper() -> None:
    base_env = gym.make(USV, disable_env_checker=True)

    class Const:
        def predict(self, obs, deterministic=True):
            return np.full((*np.shape(obs)[:-1], 1), 0.5, dtype=np.float32), None

    pol = ResidualPolicy(Const(), GeometricController(base_env), scale=0.2)
    a = evaluate(pol, USV, n_episodes=2, max_time=2.0)
    b = evaluate(Const(), USV, n_episodes=2, max_time=2.0, wrapper=lambda e: ResidualAction(e, scale=0.2))
    np.testing.assert_array_equal(a.phi_series, b.phi_series)


def test_ppo_trains_on_residual_env() -> None:
    pytest.importorskip("stable_baselines3")
    from stable_baselines3 import PPO

    env = ResidualAction(gym.make(USV, disable_env_checker=True, max_episode_steps=50))
    model = PPO("MlpPolicy", env, n_steps=64, batch_size=32, n_epochs=1, seed=0, device="cpu", verbose=0)
    model.learn(total_timesteps=128)
    obs, _ = env.reset(seed=0)
    action, _ = model.predict(obs, deterministic=True)
    assert action.shape == (1,)
    _, _, _, _, info = env.step(action)
    assert np.isfinite(info["abs_phi"])
