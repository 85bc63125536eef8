"""The environments as pure JAX functions (`vnhc_gym.envs.functional`): gymnax's interface, the
shared step's facts (the law's exponential decay, the reward's formula, the non-finite end, the
automatic reset), batches equal to single episodes, and the same physics as the Gymnasium
environments on the same states and actions."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import vnhc_gym  # noqa: F401  (registers the environments)
from vnhc_gym import make_jax
from vnhc_gym.tasks import env_ids

ENVS = env_ids("v1", shipped_only=True)


def _short(e: str) -> str:
    return e.removeprefix("vnhc_gym/")


@pytest.fixture(scope="module", params=ENVS, ids=_short)
def env_id(request: pytest.FixtureRequest) -> str:
    return str(request.param)


def test_reset_and_step_follow_gymnax(env_id: str) -> None:
    env, params = make_jax(env_id)
    obs, state = env.reset(jax.random.key(0), params)
    assert obs.shape == env.observation_space(params).shape and env.observation_space(params).contains(
        np.asarray(obs, dtype=np.float32))
    action = jnp.zeros(env.action_space(params).shape)
    obs2, state2, reward, terminated, truncated, info = env.step(jax.random.key(1), state, action, params)
    assert obs2.shape == obs.shape and reward.shape == () and terminated.dtype == jnp.bool_
    assert 0.0 <= float(reward) <= 1.0 and int(state2.time) == 1
    assert set(info) >= {"phi", "abs_phi", "abs_phi_sf", "final_observation", "terminated", "truncated"}
    # Importing and running left JAX's global precision alone.
    assert not jax.config.jax_enable_x64 and obs.dtype == jnp.float32


def test_a_batch_is_its_episodes_one_by_one(env_id: str) -> None:
    with jax.enable_x64(True):
        env, params = make_jax(env_id, "disturbance", obs_noise=0.01)
        keys = jax.random.split(jax.random.key(3), 8)
        obs, states = jax.vmap(env.reset, in_axes=(0, None))(keys, params)
        actions = jax.random.uniform(jax.random.key(4), (8, env.num_actions), minval=-1.0, maxval=1.0)
        step_keys = jax.random.split(jax.random.key(5), 8)
        batch = jax.vmap(env.step, in_axes=(0, 0, 0, None))(step_keys, states, actions, params)
        for i in (0, 5):
            o, s = env.reset(keys[i], params)
            np.testing.assert_allclose(o, obs[i], rtol=0, atol=1e-12)
            one = env.step(step_keys[i], s, actions[i], params)
            np.testing.assert_allclose(one[0], batch[0][i], rtol=0, atol=1e-12)
            np.testing.assert_allclose(one[2], batch[2][i], rtol=0, atol=1e-12)


def test_a_batch_through_resets_is_its_episodes_one_by_one() -> None:
    """Under ``jax.vmap`` the automatic reset draws new episodes only for the rows that ended; every
    row must still be what one episode stepped alone gives, through several resets, whether the
    batch is flat or nested (seeds x episodes)."""
    with jax.enable_x64(True):
        env, params = make_jax("vnhc_gym/SledCruise-v1", max_steps=7)
        n, steps, m = 16, 20, env.num_actions
        _, start = jax.vmap(env.reset, in_axes=(0, None))(jax.random.split(jax.random.key(0), n), params)
        actions = jax.random.uniform(jax.random.key(1), (steps, n, m), minval=-1.0, maxval=1.0)
        keys = jax.random.split(jax.random.key(2), (steps, n))
        flat = jax.jit(jax.vmap(env.step, in_axes=(0, 0, 0, None)))
        nested = jax.jit(jax.vmap(jax.vmap(env.step, in_axes=(0, 0, 0, None)), in_axes=(0, 0, 0, None)))
        one = jax.tree.map(lambda x: x[3], start)
        s_flat = start
        s_nested = jax.tree.map(lambda x: x.reshape(2, 8, *x.shape[1:]), start)
        ended = 0
        for t in range(steps):
            o_flat, s_flat, _, term, trunc, _ = flat(keys[t], s_flat, actions[t], params)
            o_nested, s_nested, *_ = nested(keys[t].reshape(2, 8), s_nested, actions[t].reshape(2, 8, m), params)
            o_one, one, *_ = env.step(keys[t, 3], one, actions[t, 3], params)
            ended += int(jnp.sum(term | trunc))
            np.testing.assert_allclose(o_one, o_flat[3], rtol=0, atol=1e-12)
            np.testing.assert_allclose(o_nested.reshape(n, -1), o_flat, rtol=0, atol=1e-12)
        assert ended >= n  # every row went through at least one reset (the time limit is 7 steps)


def test_the_law_in_the_loop_makes_phi_decay_like_exp_minus_k_t(env_id: str) -> None:
    """With the law at every RK4 stage (gain k) and no action, ``phi(t) = exp(-k t) phi(0)`` while
    the force bound does not bind (a large bound here)."""
    if "Flocking" in env_id:
        kwargs = {}
    else:
        kwargs = {"force_bound": 1e6}
    k = 2.0
    with jax.enable_x64(True):
        env, params = make_jax(env_id, feedback="continuous", gains=k, substeps=4, **kwargs)
        _, state = env.reset(jax.random.key(7), params)
        phi0 = env.task.system.phi(state.s, state.p)
        zero = jnp.zeros(env.num_actions)
        transition = jax.jit(env.transition)
        for i in range(10):
            state, out = transition(jax.random.key(i), state, zero, params)
        assert int(out.status) == 0
        np.testing.assert_allclose(out.phi, np.exp(-k * 10 * float(params.dt)) * phi0, rtol=1e-5, atol=1e-9)


def test_the_reward_is_the_bounded_formula_of_the_scale_free_phi(env_id: str) -> None:
    with jax.enable_x64(True):
        env, params = make_jax(env_id, reward_sigma=0.2, action_cost=0.1)
        _, state = env.reset(jax.random.key(11), params)
        a = jnp.full(env.num_actions, 0.5)
        _, out = env.transition(jax.random.key(12), state, a, params)
        np.testing.assert_allclose(float(out.reward), max(0.0, np.exp(-float(out.abs_phi_sf) / 0.2) - 0.1 * 0.25),
                                   rtol=1e-12)
        raw, raw_params = make_jax(env_id.replace("-v1", "-v0"), phi_scale=2.0)
        _, out = raw.transition(jax.random.key(12), state, a, raw_params)
        assert float(out.reward) == pytest.approx(max(-100.0, -float(out.abs_phi) / 2.0), rel=1e-12)


def test_a_non_finite_state_ends_the_episode_and_keeps_the_last_finite_one() -> None:
    with jax.enable_x64(True):
        env, params = make_jax("vnhc_gym/SledCruise-v1")
        obs, state = env.reset(jax.random.key(0), params)
        bad = state._replace(s=state.s.at[5].set(jnp.inf))
        new, out = env.transition(jax.random.key(1), bad, jnp.zeros(2), params)
        assert env.task.reasons[int(out.status) - 1] == "non_finite_state" and bool(out.terminated)
        assert float(out.reward) == 0.0 and bool(jnp.all(jnp.isfinite(out.obs)))
        assert not bool(jnp.all(jnp.isfinite(out.s_reached)))


def test_the_episode_resets_itself_at_the_time_limit_and_at_an_end() -> None:
    env, params = make_jax("vnhc_gym/SledCruise-v1", max_steps=3)
    obs, state = env.reset(jax.random.key(0), params)
    for i in range(3):
        obs, state, reward, terminated, truncated, info = env.step(jax.random.key(i + 1), state, jnp.zeros(2), params)
    assert bool(truncated) and not bool(terminated) and int(state.time) == 0
    assert not np.array_equal(np.asarray(obs), np.asarray(info["final_observation"]))
    # An end by a termination (a speed above the bound) resets too.
    _, state = env.reset(jax.random.key(9), params)
    fast = state._replace(s=state.s.at[3].set(50.0))
    _, state, _, terminated, truncated, info = env.step(jax.random.key(10), fast, jnp.zeros(2), params)
    assert bool(terminated) and not bool(truncated) and int(state.time) == 0
    assert env.task.reasons[int(info["status"]) - 1] == "speed_exceeded"


def test_a_batch_step_is_the_transition_where_nothing_ended_and_a_new_episode_where_it_did() -> None:
    """``step_batch``: the rows that go on are ``transition`` with the keys it splits; the rows that
    ended (one truncated at the time limit, one terminated by a speed above the bound) start an
    episode drawn with the reset keys, their last observation in ``final_observation``."""
    env, params = make_jax("vnhc_gym/SledCruise-v1", max_steps=3)
    n = 4
    obs, states = jax.vmap(env.reset, in_axes=(0, None))(jax.random.split(jax.random.key(0), n), params)
    states = states._replace(time=jnp.array([0, 2, 0, 1], jnp.int32), s=states.s.at[2, 3].set(50.0))
    actions = jnp.zeros((n, 2))
    key = jax.random.key(7)
    obs2, new, reward, terminated, truncated, info = env.step_batch(key, states, actions, params)
    key_step, key_reset = jax.random.split(key)
    went_on, out = jax.vmap(env.transition, in_axes=(0, 0, 0, None))(jax.random.split(key_step, n), states,
                                                                        actions, params)
    reset_obs, reset_state = jax.vmap(env.initial, in_axes=(0, None))(jax.random.split(key_reset, n), params)
    np.testing.assert_array_equal(np.asarray(truncated), [False, True, False, False])
    np.testing.assert_array_equal(np.asarray(terminated), [False, False, True, False])
    same = {"rtol": 1e-6, "atol": 1e-7}  # two compiled programs: equal to float32 rounding
    for i in range(n):
        ended = i in (1, 2)
        want_obs, want_s = (reset_obs[i], reset_state.s[i]) if ended else (out.obs[i], went_on.s[i])
        np.testing.assert_allclose(np.asarray(obs2[i]), np.asarray(want_obs), **same)
        np.testing.assert_allclose(np.asarray(new.s[i]), np.asarray(want_s), **same)
        np.testing.assert_allclose(np.asarray(info["final_observation"][i]), np.asarray(out.obs[i]), **same)
        assert int(new.time[i]) == (0 if ended else int(states.time[i]) + 1)
    np.testing.assert_allclose(np.asarray(reward), np.asarray(out.reward), **same)
    # and the reset rows are other episodes than the ones that ended
    assert not np.allclose(np.asarray(new.s[1]), np.asarray(went_on.s[1]))


def test_the_same_physics_as_the_gymnasium_environment(env_id: str) -> None:
    """On the Gymnasium environment's own states and actions, the pure step gives its next state,
    observation, reward and termination reason (float64 here; the observation to float32)."""
    import gymnasium as gym

    genv = gym.make(env_id).unwrapped
    with jax.enable_x64(True):
        env, params = genv.task.functional()
        transition = jax.jit(env.transition)
        _, template = env.reset(jax.random.key(0), params)
        rng = np.random.default_rng(0)
        for seed in range(3):
            o, _ = genv.reset(seed=seed)
            buf = genv.batch.buf
            state = template._replace(s=jnp.asarray(buf.state[0]), p=jnp.asarray(buf.params_true[0]),
                                      p_nominal=jnp.asarray(buf.params_nominal[0]), obs=jnp.asarray(buf.obs[0]))
            phi = env.task.system.phi(state.s, state.p)
            np.testing.assert_allclose(env.task.observation(state.s, phi, state.p_nominal, params.args), o,
                                       rtol=0, atol=2e-6)
            for i in range(100):
                a = rng.uniform(-1, 1, genv.action_space.shape).astype(np.float32)
                o, r, terminated, _, info = genv.step(a)
                state, out = transition(jax.random.key(i), state, jnp.asarray(a, dtype=jnp.float64), params)
                reason = env.task.reasons[int(out.status) - 1] if int(out.status) else None
                assert reason == info.get("termination_reason")
                np.testing.assert_allclose(out.s_reached if terminated else state.s, info["state"], rtol=1e-9,
                                           atol=1e-9)
                np.testing.assert_allclose(out.obs, o, rtol=0, atol=2e-6 * max(1.0, float(np.max(np.abs(o)))))
                assert float(out.reward) == pytest.approx(r, rel=1e-9, abs=1e-12)
                if terminated:
                    break
