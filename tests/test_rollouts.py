"""Seeded rollouts of every environment, checked step by step: the state follows the plain RK4 step
of the model (`ConstrainedSystem.step`, open loop) under the force ``info`` reports as applied, so the
episode's machinery (mismatch, kicks, noise, clipping, resets) adds nothing else to the physics;
``phi`` is the model's at the state, and the reward is the card's formula of what ``info`` reports.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
import pytest

from vnhc_gym.tasks import TASKS

pytestmark = pytest.mark.filterwarnings("ignore:.*is out of date:DeprecationWarning")

SCENARIOS = ("nominal", "saturated", "mismatch", "noisy", "coarse")
CASES = [(f"vnhc_gym/{TASKS[name].env_name}-{v}", scenario) for name in sorted(TASKS) for v in ("v0", "v1")
         for scenario in SCENARIOS]


def _rollout(env_id: str, scenario: str, n_steps: int = 40) -> list[dict[str, Any]]:
    env = gym.make(env_id, scenario=scenario)
    rng = np.random.default_rng(123)
    obs, info = env.reset(seed=7)
    params = info["params"]
    steps = []
    for t in range(n_steps):
        a = (rng.uniform(-1, 1, env.action_space.shape) * (1.0 if (t // 20) % 2 == 0 else 0.05)).astype(np.float32)
        before = info["state"]
        obs, reward, terminated, truncated, info = env.step(a)
        steps.append({"before": before, "action": a, "reward": reward, "info": info, "params": params,
                      "obs": obs, "terminated": terminated})
        if terminated or truncated:
            break
    steps[0]["env"] = env.unwrapped
    return steps


@pytest.mark.parametrize(("env_id", "scenario"), CASES)
def test_rollout_follows_the_model_and_the_cards_reward(env_id: str, scenario: str) -> None:
    steps = _rollout(env_id, scenario)
    env = steps[0]["env"]
    task, cfg = env.task, env.config
    model = task.model
    bound = task.force_bound
    sigma = task.reward_sigma if cfg.reward_sigma is None else cfg.reward_sigma
    for k, st in enumerate(steps):
        info = st["info"]
        if info.get("termination_reason") == "non_finite_state":
            break
        a = np.clip(st["action"].astype(np.float64), -1.0, 1.0)
        np.testing.assert_allclose(info["force"], a * bound, rtol=1e-12, err_msg=f"{env_id} step {k}: force")
        expected, _, _ = model.step(st["before"], cfg.dt, u=info["force"], params=st["params"],
                                    substeps=cfg.substeps)
        scale = 1.0 + np.abs(expected)
        assert np.all(np.abs(info["state"] - expected) <= 1e-9 * scale), f"{env_id} {scenario} step {k}: state"
        np.testing.assert_allclose(info["phi"], model.phi(info["state"], st["params"]), rtol=1e-9, atol=1e-9,
                                   err_msg=f"{env_id} step {k}: phi")
        assert info["abs_phi"] == pytest.approx(np.mean(np.abs(info["phi"])), rel=1e-12)
        cost = cfg.action_cost * np.mean(a * a)
        if cfg.reward == "raw":
            want = float(np.clip(-info["abs_phi"] / cfg.phi_scale - cost, -cfg.reward_clip, 0.0))
        else:
            x = info["abs_phi_sf"] / sigma
            shape = np.exp(-x) if cfg.reward == "bounded" else 1.0 / (1.0 + x)
            want = float(np.clip(shape - cost, 0.0, 1.0))
        assert st["reward"] == pytest.approx(want, rel=1e-9, abs=1e-12), f"{env_id} {scenario} step {k}: reward"
        assert isinstance(st["reward"], float) and isinstance(st["terminated"], bool)


@pytest.mark.parametrize("name", sorted(TASKS))
def test_a_disturbance_kicks_only_the_declared_velocities(name: str) -> None:
    """Under ``disturbance`` the state leaves the model's step only in the velocity entries the task's
    ``impulse_mask`` weights, and sometimes does (no action, over episodes until 300 steps)."""
    env = gym.make(f"vnhc_gym/{TASKS[name].env_name}-v1", scenario="disturbance")
    task, cfg = env.unwrapped.task, env.unwrapped.config
    n = task.model.n
    obs, info = env.reset(seed=3)
    params = info["params"]
    kicked = 0
    for _ in range(300):
        before = info["state"]
        obs, _, terminated, truncated, info = env.step(np.zeros(env.action_space.shape, np.float32))
        if terminated or truncated:
            obs, info = env.reset()
            params = info["params"]
            continue
        expected, _, _ = task.model.step(before, cfg.dt, u=info["force"], params=params, substeps=cfg.substeps)
        off = np.abs(info["state"] - expected) > 1e-9 * (1.0 + np.abs(expected))
        assert not off[:n].any()
        assert not off[n:][task.impulse_mask == 0].any()
        kicked += bool(off.any())
    assert kicked > 0
