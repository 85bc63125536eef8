"""The history variant on the compiled backend (vnhc_gym.wrappers.history_jax): the frames it shows
are those SB3's VecFrameStack shows and a trained agent's numpy policy stacks at evaluation."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from vnhc_gym import make_jax
from vnhc_gym.training.agents import _Network
from vnhc_gym.wrappers.history_jax import HistoryEnv


def test_the_frames_are_the_numpy_policys_through_an_automatic_reset() -> None:
    """Three episodes side by side for 9 steps, each ending at the 4-step time limit: at every step
    each row's shown frames equal `_Network`'s stack of the plain observations (zeros before an
    episode's first), the frames the agent is evaluated with."""
    env, params = make_jax("vnhc_gym/SledCruise-v1", "noisy", max_steps=4)
    hist = HistoryEnv.around(env, 4)
    d = env.obs_dim
    assert hist.obs_dim == 4 * d
    obs, state = jax.vmap(hist.reset, in_axes=(0, None))(jax.random.split(jax.random.key(0), 3), params)
    net = _Network(None, {"frame_stack": 4})
    starts = np.ones(3, bool)
    restarted = 0
    for t in range(9):
        plain = np.asarray(obs[:, -d:], np.float32)  # the newest frame is the plain observation
        np.testing.assert_array_equal(np.asarray(obs, np.float32), net._stack(plain, starts))
        if t == 0:
            np.testing.assert_array_equal(np.asarray(obs[:, :-d]), 0.0)
        action = jnp.full((3, env.num_actions), 0.3)
        before = obs
        obs, state, _, terminated, truncated, info = hist.step_batch(jax.random.key(t + 1), state, action, params)
        starts = np.asarray(terminated | truncated)
        restarted += int(starts.sum())
        # The frames an episode ended with (a truncated episode's value bootstraps on them) are its own:
        # the frames shown before the step, rolled by one.
        np.testing.assert_array_equal(np.asarray(info["final_observation"][:, :-d]), np.asarray(before[:, d:]))
    assert restarted == 6  # every row reached the time limit twice


def test_only_a_plain_environment_gets_a_history() -> None:
    env, _ = make_jax("vnhc_gym/SledCruise-v1")
    with pytest.raises(ValueError, match="frames must be an integer >= 2"):
        HistoryEnv.around(env, 1)
    with pytest.raises(ValueError, match="plain FunctionalEnv"):
        HistoryEnv.around(HistoryEnv.around(env, 2), 2)
