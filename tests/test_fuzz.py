"""Bad constructor arguments, for every registered environment: either an error that names the
argument, or an environment that survives random steps with finite observations."""

from __future__ import annotations

import math
import warnings

import gymnasium as gym
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import vnhc_gym
from vnhc_gym.envs.config import CONFIG_FIELDS
from vnhc_gym.tasks import TASKS

ENV_IDS = vnhc_gym.env_ids("v1")

#: Values that stress the checks: wrong types, non-finite, huge and tiny numbers, containers.
ODD_VALUES = st.one_of(
    st.none(), st.booleans(), st.text(max_size=5), st.lists(st.integers(), max_size=3), st.dictionaries(
        st.text(max_size=3), st.floats(allow_nan=True), max_size=2),
    st.integers(min_value=-10**40, max_value=10**40), st.just(10**400),
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([0.0, -0.0, 1e-300, 5e-324, 1e300, -1e300, math.inf, math.nan, 1e-9, 1e9]),
)


def _names(env_id: str) -> list[str]:
    entry = next(e for e in TASKS.values() if env_id.endswith(f"/{e.env_name}-v1"))
    return sorted({*CONFIG_FIELDS, *entry.task_class.Options.defaults(), "scenario", "not_an_argument"})


@pytest.mark.parametrize("env_id", ENV_IDS)
@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_bad_arguments_are_refused_by_name_or_survived(env_id: str, data: st.DataObject) -> None:
    name = data.draw(st.sampled_from(_names(env_id)), label="argument")
    value = data.draw(ODD_VALUES, label="value")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            env = gym.make(env_id, **{name: value})
    except (ValueError, TypeError) as exc:
        assert name in str(exc), f"{type(exc).__name__} for {name}={value!r} does not name it: {exc}"
        return
    rng = np.random.default_rng(0)
    obs, _ = env.reset(seed=0)
    assert np.all(np.isfinite(obs))
    for _ in range(50):
        obs, reward, terminated, truncated, info = env.step(rng.uniform(-1, 1, env.action_space.shape))
        assert np.all(np.isfinite(obs)), f"{name}={value!r}: non-finite observation {obs}"
        assert math.isfinite(reward)
        if terminated or truncated:
            assert not terminated or "termination_reason" in info
            obs, _ = env.reset()


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_every_reward_shape_survives_random_steps(env_id: str) -> None:
    """Each reward shape (random bad values never reach a valid choice) gives an environment whose
    random steps stay finite, with the reward in the range its shape promises: ``raw`` in
    ``[-reward_clip, 0]``, ``bounded`` and ``reciprocal`` at most 1 and at least ``-action_cost``."""
    from vnhc_gym.envs.config import REWARDS

    for name, value in [("reward", r) for r in REWARDS]:
        env = gym.make(env_id, **{name: value})
        cfg = env.unwrapped.config
        low = -cfg.reward_clip if cfg.reward == "raw" else -cfg.action_cost
        high = 0.0 if cfg.reward == "raw" else 1.0
        rng = np.random.default_rng(0)
        env.reset(seed=0)
        rewards = []
        for _ in range(40):
            action = rng.uniform(-1, 1, env.action_space.shape)
            obs, reward, terminated, truncated, info = env.step(action)
            assert np.all(np.isfinite(obs)), (name, value, obs)
            rewards.append(reward)
            if terminated or truncated:
                env.reset()
        assert all(low <= r <= high for r in rewards), (name, value, min(rewards), max(rewards))
        if cfg.reward == "reciprocal":  # 1 / (1 + x) from the step's own |phi~|: the shape is the one asked for
            sigma = cfg.reward_sigma if cfg.reward_sigma is not None else env.unwrapped.task.reward_sigma
            cost = cfg.action_cost * np.mean(action**2)
            expected = 1.0 / (1.0 + info["abs_phi_sf"] / sigma) - cost
            assert rewards[-1] == pytest.approx(expected, rel=1e-9, abs=1e-12)
