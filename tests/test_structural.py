"""The scenarios whose model is wrong in structure (``delay``, ``lag``, ``unmodelled``): the delay
applies old commands, the lag is a first-order actuator (its mean force against a numerical
integral of the exponential), the unmodelled forces are the physics the cards state, the hidden
quantities stay out of the observation and change once mid-episode, and the oracle that knows them
makes ``phi`` decay as ``exp(-K t)``."""

from __future__ import annotations

import math

import gymnasium as gym
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import quad

import vnhc_gym  # noqa: F401  (registers the environments)
from vnhc_gym import make_jax
from vnhc_gym.baselines import ActuatedLaw, InformedActuatedLaw, OracleController
from vnhc_gym.envs.config import SCENARIOS, STRUCTURAL
from vnhc_gym.tasks import env_ids

ENVS = env_ids("v1", shipped_only=True)
#: Held to one worker, which the collection hook hands out first: compiled early in a worker's life.
pytestmark = pytest.mark.xdist_group("test_structural")


@pytest.fixture(autouse=True, scope="module")
def _no_persistent_compilation_cache() -> object:
    """This module compiles without the run's persistent cache: in two full runs of the suite, a
    worker that had compiled most of it crashed with a segmentation fault inside XLA's
    ``executable.serialize()`` (JAX's cache write) on one of this module's programs, and took the
    run down.  Its programs compile in about a second each without the cache."""
    from jax._src import compilation_cache

    enabled = jax.config.jax_enable_compilation_cache
    jax.config.update("jax_enable_compilation_cache", False)
    compilation_cache.reset_cache()
    yield
    jax.config.update("jax_enable_compilation_cache", enabled)
    compilation_cache.reset_cache()


def _phis(env: gym.Env, policy: object, steps: int = 20) -> np.ndarray:
    """``phi`` after each of ``steps`` steps of ``policy`` from the seed-5 start."""
    obs, _ = env.reset(seed=5)
    phis = []
    for _ in range(steps):
        obs, _, _, _, info = env.step(policy.predict(obs)[0])  # type: ignore[attr-defined]
        phis.append(info["phi"])
    return np.array(phis)


def _forces(env_id: str, actions: np.ndarray, **kwargs: object) -> np.ndarray:
    env = gym.make(env_id, **kwargs)
    env.reset(seed=3)
    out = []
    for a in actions:
        out.append(env.step(a)[4]["force"])
    return np.array(out)


@pytest.mark.parametrize("env_id", ENVS)
def test_a_delay_of_d_steps_applies_the_command_of_d_steps_before(env_id: str) -> None:
    env = gym.make(env_id)
    m = env.action_space.shape[0]
    bound = env.unwrapped.task.force_bound
    rng = np.random.default_rng(0)
    actions = rng.uniform(-0.5, 0.5, (8, m))
    forces = _forces(env_id, actions, delay_min=3, delay_max=3)
    np.testing.assert_allclose(forces[:3], 0.0, atol=0)  # nothing was commanded before the start
    np.testing.assert_allclose(forces[3:], actions[:-3] * bound, rtol=1e-12)


def test_a_lag_applies_the_mean_of_a_first_order_response() -> None:
    tau, dt, c = 0.3, 0.05, 0.8
    forces = _forces("vnhc_gym/SledCruise-v1", np.full((6, 2), c), lag_min=tau, lag_max=tau)
    bound = np.array([120.0, 40.0])
    for k, f in enumerate(forces):
        # z(t) = c (1 - exp(-t / tau)) from rest; the period's force is its mean.
        mean = quad(lambda t: c * (1.0 - math.exp(-t / tau)), k * dt, (k + 1) * dt)[0] / dt
        np.testing.assert_allclose(f, mean * bound, rtol=1e-9)


def test_coulomb_friction_slows_the_sled_at_mu_g() -> None:
    """Gliding straight without slip and without force, the blade's friction is its only force:
    the forward speed falls at ``mu g``."""
    with jax.enable_x64(True):
        env, params = make_jax("vnhc_gym/SledCruise-v1", "unmodelled", redraw=False)
        _, state = env.reset(jax.random.key(0), params)
        mu = float(state.actuator.hidden[0, 2])
        assert 0.05 <= mu <= 0.3
        s = jnp.array([0.0, 0.0, 0.3, 2.0 * math.cos(0.3), 2.0 * math.sin(0.3), 0.0])
        new, _ = env.transition(jax.random.key(1), state._replace(s=s), jnp.zeros(2), params)
        speed = float(jnp.hypot(new.s[3], new.s[4]))
        np.testing.assert_allclose(speed, 2.0 - mu * 9.81 * 0.05, rtol=1e-9)
        slip = -jnp.sin(new.s[2]) * new.s[3] + jnp.cos(new.s[2]) * new.s[4]
        assert abs(float(new.s[5])) < 1e-12 and abs(float(slip)) < 1e-12


def test_the_cart_s_coulomb_friction_is_mu_times_the_weight() -> None:
    """With the pole upright and at rest, the cart's friction force ``mu (M_c + m_p) g`` (and the
    viscous friction ``b_c xd``) decelerate it as one body with the pole's reaction."""
    with jax.enable_x64(True):
        env, params = make_jax("vnhc_gym/CartPoleBalance-v1", "unmodelled", redraw=False)
        _, state = env.reset(jax.random.key(2), params)
        mu = float(state.actuator.hidden[0, 2])
        p = state.p
        s = jnp.array([0.0, 0.0, 1.0, 0.0])
        nominal = env.task.system.drift(s, p)
        extra = env.true_system(state.actuator.hidden[0], params).drift(s, p) - nominal
        y = env.task.system.input_fields(s, p)[:, 0]
        # The friction acts on the force's own line: its accelerations are Y times the force.
        force = -mu * (p[0] + p[1]) * p[3] * math.tanh(1.0 / 0.02)
        np.testing.assert_allclose(extra, y * force, rtol=1e-12)


@pytest.mark.parametrize("scenario", STRUCTURAL)
@pytest.mark.parametrize("env_id", ENVS)
def test_hidden_structure_is_not_in_the_observation(env_id: str, scenario: str) -> None:
    """The same seed starts the same episode as ``nominal``: the observation holds nothing hidden,
    and the other scenarios' episodes are untouched by the hidden draws."""
    obs_nominal, _ = gym.make(env_id).reset(seed=11)
    obs, info = gym.make(env_id, scenario=scenario).reset(seed=11)
    np.testing.assert_array_equal(obs, obs_nominal)
    assert {"delay_steps", "lag_time_constant", "unmodelled_coefficients"} <= set(info)


def test_the_hidden_quantities_are_drawn_in_range_and_again_mid_episode() -> None:
    venv = gym.make_vec("vnhc_gym/SledCruise-v1", num_envs=16, vectorization_mode="vector_entry_point",
                        scenario="delay", delay_min=2, delay_max=6)
    venv.reset(seed=0)
    first = None
    changed = np.zeros(16, dtype=bool)
    for _ in range(400):
        _, _, _, _, info = venv.step(np.zeros((16, 2)))
        d = info["delay_steps"]
        assert np.all((d >= 2) & (d <= 6))
        if first is None:
            first = d.copy()
        switch = venv.unwrapped.batch.buf.switch_at[:, 0]
        assert np.all((switch >= 100) & (switch <= 300))
        changed |= d != first
    assert changed.sum() >= 8  # 5 values: a second draw differs from the first 4 times in 5


@pytest.mark.parametrize("scenario", ["delay", "lag"])
def test_the_oracle_makes_phi_decay_exponentially_through_the_actuator(scenario: str) -> None:
    gain = 5.0
    kwargs = ({"delay_min": 3, "delay_max": 3} if scenario == "delay" else {"lag_min": 0.1, "lag_max": 0.1})
    env = gym.make("vnhc_gym/FlockingAlign-v1", redraw=False, **kwargs)
    phis = _phis(env, OracleController(env, gain=gain))
    # After the commands issued before the oracle's first plan have acted (3 steps of delay), each
    # step shrinks phi by exp(-k dt).
    start = 4 if scenario == "delay" else 1
    ratio = phis[start + 1:start + 8] / phis[start:start + 7]
    np.testing.assert_allclose(ratio, math.exp(-gain * 0.05), rtol=1e-6)


@pytest.mark.parametrize(("kwargs", "name"), [
    ({"delay_min": 4, "delay_max": 2}, "delay_max"),
    ({"delay_max": 1000}, "delay_max"),
    ({"delay_min": -1}, "delay_min"),
    ({"lag_max": 0.5}, "lag_min"),
    ({"lag_min": 0.5, "lag_max": 0.1}, "lag_max"),
    ({"unmodelled": -1.0}, "unmodelled"),
    ({"redraw": 1}, "redraw"),
])
def test_bad_structure_arguments_name_the_argument(kwargs: dict, name: str) -> None:
    with pytest.raises((ValueError, TypeError), match=name):
        gym.make("vnhc_gym/SledCruise-v1", **kwargs)


def test_every_structural_scenario_is_registered() -> None:
    assert set(STRUCTURAL) <= set(SCENARIOS)


def test_the_bank_plans_with_the_true_delay_while_the_motion_reveals_it() -> None:
    """A delay shows only while the commands change: while ``phi`` is visibly off (the start, a
    change of delay that throws it off) the hypothesis the bank plans with is the episode's delay in
    nearly every step.  On the constraint, at rest, every hypothesis predicts the same."""
    hits = excited = 0
    for seed in (3, 4, 6):
        env = gym.make("vnhc_gym/SledCruise-v1", scenario="delay")
        obs, info = env.reset(seed=seed)
        law = ActuatedLaw(env, gain=5.0, forget=0.5)
        for _ in range(400):
            obs, _, terminated, _, info = env.step(law.predict(obs)[0])
            assert not terminated
            if info["abs_phi"] > 1e-6:
                excited += 1
                hits += int(law.hyp[int(np.argmin(law._mem.error[0])), 0]) == info["delay_steps"]
    assert excited >= 100 and hits >= 0.85 * excited


def test_the_disturbance_observer_estimates_the_blade_s_friction() -> None:
    """Cruising straight without slip, the blade's friction slows the sled at ``mu g``: the rate of
    ``phi^2 = v_f - v_ref`` that the model lacks is ``-mu g``, that of the slip 0."""
    env = gym.make("vnhc_gym/SledCruise-v1", scenario="unmodelled", redraw=False)
    obs, info = env.reset(seed=4)
    mu = info["unmodelled_coefficients"][0]
    law = ActuatedLaw(env, gain=10.0, observer=0.3)
    for _ in range(300):
        obs, _, _, _, info = env.step(law.predict(obs)[0])
    np.testing.assert_allclose(law._mem.delta[0], [0.0, -mu * 9.81], atol=2e-3 * mu * 9.81 + 1e-6)
    assert info["abs_phi"] < 1e-3


def test_told_the_delay_the_law_makes_phi_decay_as_the_oracle_does() -> None:
    gain = 5.0
    env = gym.make("vnhc_gym/FlockingAlign-v1", delay_min=3, delay_max=3, redraw=False)
    phis = _phis(env, InformedActuatedLaw(env, gain=gain))
    np.testing.assert_allclose(phis[5:12] / phis[4:11], math.exp(-gain * 0.05), rtol=1e-6)


def test_the_actuated_law_applies_only_where_the_structure_is_hidden() -> None:
    from vnhc_gym.baselines.tuning import applicable

    assert not applicable("actuated_law", "vnhc_gym/SledCruise-v1", "nominal")
    assert all(applicable(name, "vnhc_gym/SledCruise-v1", s) for s in STRUCTURAL
               for name in ("actuated_law", "actuated_dob", "informed_actuated"))
