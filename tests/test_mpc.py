"""Tests of the planning baseline (`vnhc_gym.baselines.mpc`): where the force bound does not bind it
reproduces the law's exponential decay of ``phi`` (an independent fact: ``exp(-k t)``), and where
it binds it beats the clipped law on validation episodes."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import vnhc_gym  # noqa: F401  (registers the environments)
from vnhc_gym.baselines import GeometricController, make_classical
from vnhc_gym.baselines.mpc import MPCController
from vnhc_gym.evaluation import VALIDATION_SEED, evaluate
from vnhc_gym.tasks import env_ids

ENVS = env_ids("v1", shipped_only=True)


@pytest.mark.parametrize("env_id", ENVS, ids=lambda e: e.removeprefix("vnhc_gym/"))
def test_mpc_reproduces_the_laws_decay_where_the_bound_does_not_bind(env_id: str) -> None:
    env = gym.make(env_id, scenario="nominal")
    obs, info = env.reset(seed=VALIDATION_SEED)
    mpc = MPCController(env, gain=5.0)
    dt = env.unwrapped.task.config.dt
    phi = [np.atleast_1d(info["phi"]).copy()]
    for _ in range(8):
        action, _ = mpc.predict(obs)
        assert np.all(np.abs(action) < 1.0)  # the bound does not bind
        obs, _, terminated, truncated, info = env.step(action)
        assert not (terminated or truncated)
        phi.append(np.atleast_1d(info["phi"]).copy())
    expected = phi[0] * np.exp(-5.0 * dt * np.arange(len(phi)))[:, None]
    # Within 5 %: the plan follows the law's decay over a finite horizon, with the bound as a penalty.
    assert np.max(np.abs(np.array(phi) - expected)) < 5e-2 * np.max(np.abs(phi[0]))
    assert mpc.n_solves == 8 and mpc.solve_seconds > 0


def test_mpc_stays_with_the_clipped_law_where_the_bound_binds() -> None:
    """The sled with its thrust and torque bounds lowered (``saturated``): clipping each force of the
    law separately bends the direction it asked for, while the plan allocates both within their
    bounds.  At the law's gain the two score within 1 % of each other (measured: the plan 0.5458, the
    clipped law 0.5473 over these 8 episodes), so the plan is a fair candidate, not a free win."""
    env_id = "vnhc_gym/SledCruise-v1"
    laws: list[GeometricController] = []

    def law(env: gym.Env) -> GeometricController:
        laws.append(GeometricController(env))
        return laws[-1]

    kw = {"n_episodes": 8, "seed": VALIDATION_SEED, "max_time": 4.0}
    clipped = evaluate(law, env_id, "saturated", **kw)
    planned = evaluate(lambda env: MPCController(env, gain=5.0), env_id, "saturated", **kw)
    assert laws[0].n_saturated > 0  # the bound binds
    assert planned.metrics["score"].mean() == pytest.approx(clipped.metrics["score"].mean(), rel=0.01)


def test_mpc_is_a_tunable_classical_baseline_and_refuses_bad_settings() -> None:
    env = gym.make("vnhc_gym/USVStream-v1")
    pol = make_classical("mpc", env, gain=10.0, horizon=4)
    assert isinstance(pol, MPCController) and pol.name == "mpc" and pol.horizon == 4
    for kwargs, match in (({"horizon": 0}, "horizon"), ({"iters": 1.5}, "iters"),
                          ({"gain": -1.0}, "gain"), ({"limit_weight": -1.0}, "limit_weight"),
                          ({"limit_margin": 0.0}, "limit_margin")):
        with pytest.raises(ValueError, match=match):
            MPCController(env, **kwargs)  # type: ignore[arg-type]


def test_mpc_keeps_the_state_inside_a_limit_the_unpenalised_plan_leaves() -> None:
    """The sled's turn-rate limit set to 0.8 of each start's turn rate: the plan that ignores the
    limit (``limit_weight=0``) lets it end at least one episode; the penalised plan ends none."""
    ends = {0.0: 0, 1e4: 0}
    for ep in range(5):
        probe = gym.make("vnhc_gym/SledCruise-v1")
        _, info = probe.reset(seed=VALIDATION_SEED + ep)
        limit = 0.8 * abs(info["state"][5])
        for weight in ends:
            env = gym.make("vnhc_gym/SledCruise-v1", max_episode_steps=20, max_turn_rate=limit)
            mpc = MPCController(env, gain=5.0, limit_weight=weight)
            obs, _ = env.reset(seed=VALIDATION_SEED + ep)
            for _ in range(20):
                obs, _, terminated, truncated, info = env.step(mpc.predict(obs)[0])
                if terminated or truncated:
                    ends[weight] += info.get("termination_reason") == "turn_rate_exceeded"
                    break
    assert ends[0.0] >= 1 and ends[1e4] == 0


def test_an_episodes_plan_does_not_depend_on_its_batch() -> None:
    """Each episode is its own problem, warm-started from its own last plan: one episode's actions are
    the same alone and as one row of a batch of 8 (the saturated sled, where the bound binds)."""
    env_id = "vnhc_gym/SledCruise-v1"
    seeds = [VALIDATION_SEED + i for i in range(8)]
    vec = gym.make_vec(env_id, num_envs=8, vectorization_mode="vector_entry_point", scenario="saturated")
    alone = gym.make(env_id, scenario="saturated")
    batch_obs, _ = vec.reset(seed=seeds)
    obs, _ = alone.reset(seed=seeds[3])
    batched, single = MPCController(vec, gain=5.0, horizon=4), MPCController(alone, gain=5.0, horizon=4)
    for _ in range(6):
        a_batch, _ = batched.predict(batch_obs)
        a_alone, _ = single.predict(obs)
        np.testing.assert_array_equal(a_batch[3], a_alone)
        batch_obs, *_ = vec.step(a_batch)
        obs, *_ = alone.step(a_alone)
