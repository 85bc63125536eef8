"""Property tests (hypothesis) of every registered environment's input handling.

* Any action array of the right shape is either stepped (finite outcome, force ``clip(a) *
  bound``, observation in the space, reward in the version's range) or, if it holds a NaN or an
  infinity, refused with a ``ValueError`` naming ``action`` without touching the episode (a twin
  env that only gets the accepted actions stays identical).
* Any keyword arguments, drawn from valid and invalid values of the shared configuration and of
  the task's own options (read from the registry), give either a ``ValueError`` / ``TypeError``
  naming a bad argument or a working env whose steps are finite and inside the spaces; never
  another exception, a warning or a NaN.

Valid option values stay within the compiled systems (task options keep their default unless
they are real numbers, which are scaled), so no example triggers a fresh compilation.
"""

from __future__ import annotations

import math
import numbers
import warnings
from dataclasses import fields
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from vnhc_gym.envs.config import SCENARIOS
from vnhc_gym.tasks import env_ids, task_of_env_id

NAN, INF = float("nan"), float("inf")
# 15 examples per id and test (each draws a scenario and up to 12 actions, or a whole set of
# keywords), over every registered id.
SETTINGS = settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow])
ALL_IDS = env_ids(None)


def env_class(env_id: str) -> type:
    entry = task_of_env_id(env_id)
    return getattr(entry.load(), f"{entry.env_name}Env")


def reward_bounds(env_id: str, env: gym.Env) -> tuple[float, float]:
    return (0.0, 1.0) if env_id.endswith("-v1") else (-env.unwrapped.config.reward_clip, 0.0)


# --------------------------------------------------------------------------- actions

special = st.sampled_from([NAN, INF, -INF, 0.0, -0.0, 1.0, -1.0, 1e-300, -5e-324, 1e300, -1e300, 1.0000001])
number = st.one_of(st.floats(allow_nan=True, allow_infinity=True, width=64), special,
                   st.floats(-2.0, 2.0), st.floats(-1e-6, 1e-6))


def _array(xs: list[float], dtype: type) -> np.ndarray:
    with np.errstate(over="ignore"):  # huge draws become inf in float32: part of the input
        return np.array(xs, dtype=np.float64).astype(dtype)


def action_arrays(m: int) -> st.SearchStrategy[np.ndarray]:
    return st.tuples(st.lists(number, min_size=m, max_size=m), st.sampled_from([np.float32, np.float64])).map(
        lambda t: _array(*t))


@pytest.mark.filterwarnings("ignore:.*is out of date:DeprecationWarning")
@pytest.mark.parametrize("env_id", ALL_IDS)
@SETTINGS
@given(data=st.data())
def test_any_action_is_stepped_or_refused(env_id: str, data: st.DataObject) -> None:
    scenario = data.draw(st.sampled_from(sorted(SCENARIOS)), label="scenario")
    env, twin = gym.make(env_id, scenario=scenario), gym.make(env_id, scenario=scenario)
    m = env.action_space.shape[0]
    acts = data.draw(st.lists(action_arrays(m), min_size=1, max_size=12), label="actions")
    lo, hi = reward_bounds(env_id, env)
    bound = env.unwrapped.task.force_bound
    env.reset(seed=0)
    twin.reset(seed=0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for a in acts:
            if not np.all(np.isfinite(a)):
                with pytest.raises(ValueError, match=r"\baction\b"):
                    env.step(a)
                continue
            obs, r, term, trunc, info = env.step(a)
            t_obs, t_r, *_ = twin.step(a.copy())
            np.testing.assert_array_equal(obs, t_obs)
            assert r == t_r
            assert env.observation_space.contains(obs) and np.all(np.isfinite(obs))
            assert math.isfinite(r) and lo <= r <= hi
            if env.unwrapped.config.structural:  # a delay or a lag applies an earlier or a lagged command
                assert np.all(np.abs(info["force"]) <= bound * (1 + 1e-12))
            else:
                # atol: XLA flushes subnormal numbers to zero (an action of 5e-324 gives a force of 0)
                np.testing.assert_allclose(info["force"], np.clip(a.astype(np.float64), -1, 1) * bound, rtol=1e-15,
                                           atol=1e-300)
            if term or trunc:
                env.reset()
                twin.reset()


# --------------------------------------------------------------------------- keyword arguments


def pos(lo: float, hi: float, bad: tuple = (0.0, -1.0, NAN, INF, -INF)) -> tuple[Any, Any]:
    """(valid values in [lo, hi], invalid values)."""
    return st.floats(lo, hi), st.sampled_from(bad)


def choice(valid: list, invalid: list) -> tuple[Any, Any]:
    return st.sampled_from(valid), st.sampled_from(invalid)


#: Shared keyword -> (strategy of valid values, strategy of invalid values).
COMMON = {
    "scenario": choice(sorted(SCENARIOS), ["bogus", "", 3]),
    "dt": pos(1e-3, 0.5),
    "substeps": (st.integers(1, 6), st.sampled_from([0, -1, 1.5, True, None])),
    "force_bound": (st.one_of(st.floats(1e-3, 1e4), st.none()), st.sampled_from([0.0, -1.0, NAN, INF, 1e31, "1"])),
    "force_bound_scale": pos(1e-3, 10.0),
    "reward": choice(["raw", "bounded"], ["shaped", None]),
    "reward_sigma": (st.one_of(st.floats(1e-2, 10.0), st.none()), st.sampled_from([0.0, -1.0, NAN])),
    "phi_scale": pos(1e-3, 1e3),
    "action_cost": pos(0.0, 10.0, bad=(-0.5, NAN, INF)),
    "reward_clip": pos(1e-2, 1e3),
    "param_mismatch": pos(0.0, 0.95, bad=(1.0, 1.5, -0.1, NAN)),
    "obs_noise": pos(0.0, 1.0, bad=(-0.1, NAN, INF)),
    "impulse_prob": pos(0.0, 1.0, bad=(-0.1, 1.1, NAN)),
    "impulse_scale": (st.one_of(st.floats(1e-3, 5.0), st.none()), st.sampled_from([0.0, -1.0, NAN])),
    "obs_clip": pos(1e-2, 100.0, bad=(0.0, -1.0, NAN, INF, 1e39)),
    "render_mode": choice([None, "rgb_array"], ["text", "ansi", []]),
}


def option_strategies(default: Any) -> tuple[Any, Any]:
    """A task option's (valid, invalid) values from its default: real numbers are scaled by
    [0.5, 2] (and refuse text and non-finite numbers), everything else keeps its default (another
    system would be compiled) and refuses values of the wrong kind."""
    if isinstance(default, bool):
        return st.just(default), st.sampled_from(["abc", 3.5])
    if isinstance(default, numbers.Integral):
        return st.just(default), st.sampled_from(["abc", 2.5, -1])
    if isinstance(default, numbers.Real) and default > 0:
        return st.floats(0.5, 2.0).map(lambda f: default * f), st.sampled_from(["abc", NAN, INF, [default]])
    if isinstance(default, str):
        return st.just(default), st.sampled_from(["no-such-name", 3.5])
    return st.just(default), st.sampled_from(["no-such-name", 3.5, object()])


def keyword_table(env_id: str) -> dict[str, tuple[Any, Any]]:
    """Every keyword's strategies; a task option's valid values stay inside its declared bounds."""
    table = dict(COMMON)
    for f in fields(task_of_env_id(env_id).task_class.Options):
        valid, invalid = option_strategies(f.default)
        check = f.metadata.get("check") or {}
        if check.get("kind") == "number" and isinstance(f.default, float):
            lo, hi = check.get("low"), check.get("high")
            valid = valid.map(lambda v, lo=lo, hi=hi: min(max(v, lo if lo is not None else v), hi if hi is not None
                                                          else v))
        table[f.name] = (valid, invalid)
    return table


def draw_kwargs(data: st.DataObject, env_id: str) -> tuple[dict, list[str]]:
    """Some keywords with valid values and, in about half of the examples, one or two invalid ones."""
    table = keyword_table(env_id)
    chosen = data.draw(st.lists(st.sampled_from(sorted(table)), unique=True, max_size=8), label="keywords")
    n_bad = min(len(chosen), data.draw(st.sampled_from([0, 0, 1, 2]), label="n_bad"))
    kwargs = {}
    for i, name in enumerate(chosen):
        valid, invalid = table[name]
        kwargs[name] = data.draw(invalid if i < n_bad else valid, label=name)
    bad = chosen[:n_bad]
    if data.draw(st.integers(0, 9), label="unknown keyword?") == 0:
        kwargs["bogus_keyword"] = 1.0
        bad.append("bogus_keyword")
    return kwargs, bad


@pytest.mark.parametrize("env_id", ALL_IDS)
@SETTINGS
@given(data=st.data())
def test_any_keywords_give_a_working_env_or_a_named_error(env_id: str, data: st.DataObject) -> None:
    kwargs, bad = draw_kwargs(data, env_id)
    cls = env_class(env_id)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        try:
            # The class itself (with the registered version's arguments): gym.make checks render_mode
            # on its own before the env is built.
            env = cls(**{**gym.spec(env_id).kwargs, **kwargs})
        except (ValueError, TypeError) as e:
            event(type(e).__name__)
            assert bad, f"{type(e).__name__} for valid keyword arguments: {e}"
            assert any(name in str(e) for name in bad), f"{e} names none of {bad}"
            return
    event("env built")
    assert not bad, f"accepted invalid {bad}"
    env = gym.wrappers.TimeLimit(gym.wrappers.PassiveEnvChecker(env), max_episode_steps=400)
    reasons = env.unwrapped.task.all_reasons[1:]
    lo, hi = (0.0, 1.0) if env.unwrapped.config.reward == "bounded" else (-env.unwrapped.config.reward_clip, 0.0)
    env.action_space.seed(0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        obs, info = env.reset(seed=data.draw(st.integers(0, 2**32 - 1), label="seed"))
        assert env.observation_space.contains(obs)
        for _ in range(15):
            obs, r, term, trunc, info = env.step(env.action_space.sample())
            assert env.observation_space.contains(obs) and np.all(np.isfinite(obs))
            assert math.isfinite(r) and lo <= r <= hi
            assert np.all(np.isfinite(info["phi"])) and math.isfinite(info["abs_phi"])
            if term:
                assert info["termination_reason"] in reasons
            if term or trunc:
                obs, info = env.reset()
        if kwargs.get("render_mode") == "rgb_array":
            pytest.importorskip("pygame")
            frame = env.render()
            assert frame.dtype == np.uint8 and frame.ndim == 3 and frame.shape[2] == 3
    env.close()
