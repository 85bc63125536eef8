"""Property tests of the environments' input handling (hypothesis).

* Any action array of the right shape is either stepped (finite outcome, force ``clip(a) *
  bound``) or, if it holds a NaN or an infinity, refused with ``ValueError`` without touching the
  episode (a twin env that only gets the accepted actions ends up identical).
* Any keyword arguments, drawn from valid and invalid values, give either ``ValueError`` or a
  working env whose steps are finite and inside the spaces; never another exception, a warning
  or a NaN.

Ranges stay within the systems the numba cache already holds (``n_agents=4``; the random,
north-east and anticyclone currents), so no example triggers a fresh compilation.
"""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

import vnhc_gym
from vnhc_gym.envs import SCENARIOS, FlockingAlignEnv, USVStreamEnv

FLOCK, USV = "vnhc_gym/FlockingAlign-v0", "vnhc_gym/USVStream-v0"
CLASSES = {FLOCK: FlockingAlignEnv, USV: USVStreamEnv}
PRESET_OVERRIDES = {FLOCK: ("n_agents", "masses", "g"), USV: ("mass", "inertia", "current_params")}
N_ACT = {FLOCK: 3, USV: 1}
BOUND = {FLOCK: 250.0, USV: 100.0}
NAN, INF = float("nan"), float("inf")
SETTINGS = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])

# --------------------------------------------------------------------------- actions

special = st.sampled_from([NAN, INF, -INF, 0.0, -0.0, 1.0, -1.0, 1e-300, -5e-324, 1e300, -1e300, 1.0000001])
number = st.one_of(st.floats(allow_nan=True, allow_infinity=True, width=64), special,
                   st.floats(-2.0, 2.0), st.floats(-1e-6, 1e-6))


def _array(xs: list[float], dtype: type) -> np.ndarray:
    with np.errstate(over="ignore"):  # huge draws become inf in float32: part of the input
        return np.array(xs, dtype=np.float64).astype(dtype)


def action_arrays(m: int):
    return st.tuples(st.lists(number, min_size=m, max_size=m), st.sampled_from([np.float32, np.float64])).map(
        lambda t: _array(*t))


@pytest.mark.filterwarnings("error")
@pytest.mark.parametrize("env_id", vnhc_gym.ENV_IDS)
@SETTINGS
@given(data=st.data())
def test_any_action_is_stepped_or_refused(env_id, data):
    m = N_ACT[env_id]
    actions = data.draw(st.lists(action_arrays(m), min_size=1, max_size=12), label="actions")
    scenario = data.draw(st.sampled_from(sorted(SCENARIOS)), label="scenario")
    env, twin = gym.make(env_id, scenario=scenario), gym.make(env_id, scenario=scenario)
    env.reset(seed=0)
    twin.reset(seed=0)
    for a in actions:
        if not np.all(np.isfinite(a)):
            with pytest.raises(ValueError, match="finite"):
                env.step(a)
            continue
        obs, r, term, trunc, info = env.step(a)
        t_obs, t_r, *_ = twin.step(a.copy())
        np.testing.assert_array_equal(obs, t_obs)
        assert r == t_r
        assert env.observation_space.contains(obs) and np.all(np.isfinite(obs))
        assert math.isfinite(r) and -100.0 <= r <= 0.0
        assert np.all(np.isfinite(info["phi"]))
        bound = BOUND[env_id] * (0.05 if scenario == "saturated" else 1.0)
        np.testing.assert_allclose(info["force"], np.clip(a.astype(np.float64), -1, 1) * bound, rtol=1e-15)
        if term or trunc:
            env.reset()
            twin.reset()


# --------------------------------------------------------------------------- keyword arguments


def pos(lo: float, hi: float, bad=(0.0, -1.0, NAN, INF, -INF)):
    """(valid values in [lo, hi], invalid values)."""
    return st.floats(lo, hi), st.sampled_from(bad)


def choice(valid, invalid):
    return st.sampled_from(valid), st.sampled_from(invalid)


#: keyword -> (strategy of valid values, strategy of invalid values)
COMMON = {
    "scenario": choice(list(SCENARIOS), ["bogus", ""]),
    "dt": pos(1e-3, 0.5),
    "substeps": (st.integers(1, 6), st.sampled_from([0, -1, 1.5, True, None])),
    "force_bound": (st.one_of(st.floats(1e-3, 1e4), st.none()), st.sampled_from([0.0, -1.0, NAN, INF])),
    "force_bound_scale": pos(1e-3, 10.0),
    "phi_scale": pos(1e-3, 1e3),
    "action_cost": pos(0.0, 10.0, bad=(-0.5, NAN, INF)),
    "reward_clip": pos(1e-2, 1e3),
    "param_mismatch": pos(0.0, 0.95, bad=(1.0, 1.5, -0.1, NAN)),
    "obs_noise": pos(0.0, 1.0, bad=(-0.1, NAN, INF)),
    "impulse_prob": pos(0.0, 1.0, bad=(-0.1, 1.1, NAN)),
    "impulse_scale": (st.one_of(st.floats(1e-3, 5.0), st.none()), st.sampled_from([0.0, -1.0, NAN])),
    "obs_clip": pos(1e-2, 100.0),
    "render_mode": choice([None, "rgb_array"], ["text", "ansi"]),
}
SPECIFIC = {
    FLOCK: {
        "preset": choice([None, "paper"], ["paper-northeast", "bogus"]),
        "n_agents": choice([4], [1, 0, -2, 2.5, True]),
        "masses": (st.one_of(st.floats(1e-2, 1e2), st.lists(st.floats(1e-2, 1e2), min_size=4, max_size=4)),
                   st.sampled_from([0.0, -2.0, NAN, [2.0, 2.0, 2.0], [2.0, 2.0, 2.0, -1.0], [2.0, NAN, 2.0, 2.0]])),
        "g": pos(1e-2, 1e2),
    },
    USV: {
        "preset": choice([None, "paper-northeast", "paper-anticyclone"], ["paper", "bogus"]),
        "current": choice(["random", "northeast", "anticyclone"], ["gulfstream"]),
        "current_params": choice([None], [{"zz": 1.0}]),
        "mass": pos(1e-1, 1e3),
        "inertia": pos(1e-1, 1e2),
        "domain": pos(1.0, 1e3),
    },
}


def draw_kwargs(data, env_id: str) -> tuple[dict, list[str]]:
    """Some keywords with valid values and, in about half of the examples, one or two invalid ones."""
    table = {**COMMON, **SPECIFIC[env_id]}
    names = sorted(table)
    chosen = data.draw(st.lists(st.sampled_from(names), unique=True, max_size=8), label="keywords")
    n_bad = min(len(chosen), data.draw(st.sampled_from([0, 0, 1, 2]), label="n_bad"))
    kwargs = {}
    for i, name in enumerate(chosen):
        valid, invalid = table[name]
        kwargs[name] = data.draw(invalid if i < n_bad else valid, label=name)
    bad = chosen[:n_bad]
    if data.draw(st.integers(0, 19), label="unknown keyword?") == 0:
        kwargs["bogus_keyword"] = 1.0
        bad.append("bogus_keyword")
    return kwargs, bad


@pytest.mark.filterwarnings("error")
@pytest.mark.parametrize("env_id", vnhc_gym.ENV_IDS)
@SETTINGS
@given(data=st.data())
def test_any_keywords_give_a_working_env_or_value_error(env_id, data):
    kwargs, bad = draw_kwargs(data, env_id)
    if kwargs.get("preset") is not None and "preset" not in bad:
        # A preset sets these itself and ignores the keywords (docstrings: "the paper's masses, g and initial
        # state"); the USV env still checks the current's name first.
        bad = [b for b in bad if b not in PRESET_OVERRIDES[env_id]]
    try:
        # The class itself: gym.make warns on its own about an unknown render_mode before the env is built.
        env = CLASSES[env_id](**kwargs)
    except ValueError:
        event("ValueError")
        assert bad, "ValueError for valid keyword arguments"
        return
    event("env built")
    assert not bad, f"accepted invalid {bad}"
    env = gym.wrappers.TimeLimit(gym.wrappers.PassiveEnvChecker(env), max_episode_steps=400)
    env.action_space.seed(0)
    obs, info = env.reset(seed=data.draw(st.integers(0, 2**32 - 1), label="seed"))
    assert env.observation_space.contains(obs)
    for _ in range(15):
        obs, r, term, trunc, info = env.step(env.action_space.sample())
        assert env.observation_space.contains(obs) and np.all(np.isfinite(obs))
        assert math.isfinite(r) and -env.unwrapped.config.reward_clip <= r <= 0.0
        assert np.all(np.isfinite(info["phi"])) and math.isfinite(info["abs_phi"])
        if term:
            assert info["termination_reason"] in ("non_finite_state", "out_of_domain",
                                                     "turn_rate_exceeded")
        if term or trunc:
            obs, info = env.reset()
    if kwargs.get("render_mode") == "rgb_array":
        frame = env.render()
        assert frame.shape == (500, 500, 3) and frame.dtype == np.uint8
    env.close()
