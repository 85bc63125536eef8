"""The single environments of every registered task: API, determinism, rewards, episode ends,
scenarios, bad input, rendering and the physics the env cards state.

Every test over environments takes its ids from the registry (the ``any_id`` / ``v1_id`` /
``v0_id`` fixtures of ``conftest.py``).  Expected values come from independent sources: the env
cards (the behaviour spec), closed forms typed out here in numpy, the original paper's presets,
exact facts of RK4 (a constant acceleration is integrated exactly) and twin environments that
differ in one setting.  Nothing is compared with the code's own output pasted in.
"""

from __future__ import annotations

import copy
import inspect
import math
import pickle
import re
import warnings
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils import passive_env_checker
from gymnasium.utils.env_checker import check_env as gym_check_env

import vnhc_gym
from vnhc_gym.baselines import GeometricController, RandomPolicy, ZeroPolicy
from vnhc_gym.envs.config import SCENARIOS
from vnhc_gym.envs.env import ConstraintEnv
from vnhc_gym.envs.vector import ConstraintVectorEnv
from vnhc_gym.tasks import TASKS, env_ids, task_of_env_id
from vnhc_gym.tasks import env_id as make_env_id

pytestmark = pytest.mark.filterwarnings("ignore:.*is out of date:DeprecationWarning")

FLOCK, USV = "vnhc_gym/FlockingAlign-v1", "vnhc_gym/USVStream-v1"
needs_flocking = pytest.mark.skipif("flocking" not in TASKS, reason="the flocking task is not registered")
needs_usv = pytest.mark.skipif("usv" not in TASKS, reason="the USV task is not registered")
#: Sections every env card has (Gymnasium's documentation layout).
CARD_SECTIONS = ("## Description", "## Action Space", "## Observation Space", "## Rewards", "## Starting State",
                 "## Episode End", "## Info", "## Version History")
INFO_KEYS = {"phi", "abs_phi", "abs_phi_sf", "state", "force", "time"}


# --------------------------------------------------------------------------- helpers


def version(env_id: str) -> str:
    return env_id.rsplit("-", 1)[1]


def task(env: gym.Env) -> Any:
    return env.unwrapped.task


def action_seq(env: gym.Env, n: int, seed: int = 1234, lo: float = -1.2, hi: float = 1.2) -> np.ndarray:
    """Fixed float32 actions, some outside [-1, 1] (exercises the clipping)."""
    return np.random.default_rng(seed).uniform(lo, hi, size=(n, *env.action_space.shape)).astype(np.float32)


def reward_range(env_id: str, env: Any) -> tuple[float, float]:
    """The card: ``-v1`` rewards lie in [0, 1], ``-v0`` ones in [-reward_clip, 0] (single or vector env)."""
    return (0.0, 1.0) if version(env_id) == "v1" else (-env.unwrapped.config.reward_clip, 0.0)


def rollout(env: gym.Env, seed: int, actions: np.ndarray, meddle: bool = False) -> list[Any]:
    """Every output of a seeded rollout with fixed actions, resetting (without a seed) at episode ends."""
    out: list[Any] = [env.reset(seed=seed)]
    for k, a in enumerate(actions):
        if meddle:  # the global numpy generator must play no part
            np.random.seed(k)  # noqa: NPY002
            np.random.rand(7)  # noqa: NPY002
        step = env.step(a)
        out.append(step)
        if step[2] or step[3]:
            out.append(env.reset())
    return out


def poke_velocities(env: gym.Env, value: float, row: int = 0) -> None:
    """Set every velocity of the current state to ``value`` (finite, but the next RK4 step overflows)."""
    buf = env.unwrapped.batch.buf
    n = buf.state.shape[1] // 2
    buf.state[row, n:] = value


# --------------------------------------------------------------------------- registry and API


@pytest.mark.parametrize("name", sorted(TASKS))
def test_registry_entry_defines_both_classes_and_both_versions(name: str) -> None:
    entry = TASKS[name]
    module = entry.load()
    env_cls = getattr(module, f"{entry.env_name}Env")
    vec_cls = entry.vector_class
    assert issubclass(env_cls, ConstraintEnv) and issubclass(vec_cls, ConstraintVectorEnv)
    assert vec_cls is getattr(module, f"{entry.env_name}VectorEnv")  # importable (and picklable) by name
    assert vec_cls.env_class is env_cls and entry.task_class is env_cls.task_class
    assert env_cls.task_class.name == name
    card = inspect.getdoc(env_cls) or ""
    for section in CARD_SECTIONS:
        assert section in card, f"{entry.env_name}Env's card lacks {section!r}"
    for v, extra in (("v0", {"reward": "raw"}), ("v1", {})):
        env_id = f"vnhc_gym/{entry.env_name}-{v}"
        assert env_id in env_ids(v) and env_id in env_ids(None)
        spec = gym.spec(env_id)
        assert spec.entry_point == f"{entry.module}:{entry.env_name}Env"
        assert spec.vector_entry_point(num_envs=2).unwrapped.__class__ is vec_cls
        assert spec.kwargs == extra
        assert spec.max_episode_steps == vnhc_gym.MAX_EPISODE_STEPS == 400
        assert task_of_env_id(env_id) is entry


def test_registered_ids_are_exactly_the_registry() -> None:
    ours = {i for i in gym.registry if i.startswith("vnhc_gym/")}
    assert ours == set(env_ids(None)) == set(env_ids("v0")) | set(env_ids("v1"))
    assert len(env_ids(None)) == 2 * len(TASKS)


def test_made_env_matches_its_card_and_version(any_id: str) -> None:
    env = gym.make(any_id)
    raw = env.unwrapped
    entry = task_of_env_id(any_id)
    assert type(raw) is getattr(entry.load(), f"{entry.env_name}Env")
    assert raw.config.reward == ("raw" if version(any_id) == "v0" else "bounded")
    assert raw.dt == raw.config.dt == 0.05 and raw.config.substeps == 1
    assert set(raw.metadata["render_modes"]) == {"human", "rgb_array"} and raw.metadata["render_fps"] > 0
    t = task(env)
    assert env.action_space == gym.spaces.Box(-1.0, 1.0, (t.act_dim,), np.float32)
    assert env.observation_space == gym.spaces.Box(-10.0, 10.0, (t.obs_dim,), np.float32)
    assert gym.make(any_id, scenario="coarse").unwrapped.dt == 0.1
    env.close()


def test_gymnasium_and_sb3_checkers_pass_without_warnings(any_id: str) -> None:
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        gym_check_env(gym.make(any_id).unwrapped)
        gym_check_env(gym.make(any_id))  # through gym.make's wrappers too
        sb3_check_env(gym.make(any_id).unwrapped, warn=True)
        sb3_check_env(gym.make(any_id), warn=True)
    # Gymnasium always advises to check env.unwrapped when given a wrapper, and gym.make warns that
    # -v0 is not the latest version: neither is about the environment.
    whitelist = ("is different from the unwrapped version", "is out of date")
    left = [f"{w.category.__name__}: {w.message}" for w in caught if not any(s in str(w.message) for s in whitelist)]
    assert not left


def test_passive_checker_is_silent_over_long_rollouts(id_scenario: tuple[str, str]) -> None:
    """Gymnasium's passive checks of every reset and step (observation in the space, reward a
    finite float, flags bools, ...) never warn, over episodes ending by termination and truncation;
    a termination carries one of the task's reasons, and no other step does."""
    any_id, scenario = id_scenario
    env = gym.make(any_id, scenario=scenario, max_episode_steps=60).unwrapped
    reasons = set(task(env).all_reasons[1:])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        passive_env_checker.check_action_space(env.action_space)
        passive_env_checker.check_observation_space(env.observation_space)
        passive_env_checker.env_reset_passive_checker(env, seed=5)
        steps = 0
        for a in action_seq(env, 240, seed=6, lo=-3.0, hi=3.0):
            obs, r, term, trunc, info = passive_env_checker.env_step_passive_checker(env, a)
            steps += 1
            assert env.observation_space.contains(obs)
            assert type(r) is float and type(term) is bool
            assert (info.get("termination_reason") in reasons) if term else "termination_reason" not in info
            if term or steps == 60:
                passive_env_checker.env_reset_passive_checker(env)
                steps = 0


# --------------------------------------------------------------------------- infos and rewards


def test_info_holds_the_documented_entries(any_id: str, env_cache) -> None:
    env = env_cache(any_id, scenario="mismatch")
    t = task(env)
    n, m = t.model.n, t.act_dim
    obs, info = env.reset(seed=3)
    assert set(info) == INFO_KEYS | {"params"}
    np.testing.assert_array_equal(info["params"], env.unwrapped.batch.buf.params_true[0])
    assert info["params"].shape == (len(t.model.param_names),) and info["time"] == 0.0
    np.testing.assert_array_equal(info["force"], np.zeros(m))
    for k, a in enumerate(action_seq(env, 30, lo=-1.0, hi=1.0), start=1):
        obs, r, term, trunc, info = env.step(a)
        assert set(info) == INFO_KEYS | ({"termination_reason"} if term else set())
        for key, shape in (("phi", (m,)), ("state", (2 * n,)), ("force", (m,))):
            assert info[key].dtype == np.float64 and info[key].shape == shape, key
        assert type(info["abs_phi"]) is float and type(info["abs_phi_sf"]) is float
        assert info["abs_phi"] == pytest.approx(np.mean(np.abs(info["phi"])), rel=1e-12, abs=0.0)
        assert info["time"] == k * env.unwrapped.dt
        # Open loop: the applied force is the clipped action times the force bound.
        np.testing.assert_allclose(info["force"], np.clip(a.astype(np.float64), -1, 1) * t.force_bound, rtol=1e-15)
        if term or trunc:
            break


@pytest.mark.parametrize("settings", [{}, {"phi_scale": 2.0, "action_cost": 0.5, "reward_clip": 0.3,
                                           "reward_sigma": 0.2}], ids=["defaults", "custom"])
def test_reward_is_the_documented_function_of_phi(any_id: str, settings: dict, env_cache) -> None:
    """-v1: ``clip(exp(-|phi~| / sigma) - c mean(a^2), 0, 1)`` with the task's default sigma;
    -v0: ``clip(-|phi| / phi_scale - c mean(a^2), -reward_clip, 0)`` (``a`` the clipped action)."""
    env = env_cache(any_id, **settings)
    t = task(env)
    sigma = settings.get("reward_sigma", type(t).reward_sigma)
    cost, scale, clip = settings.get("action_cost", 0.0), settings.get("phi_scale", 1.0), settings.get("reward_clip")
    env.reset(seed=2)
    for a in action_seq(env, 80, lo=-1.5, hi=1.5):
        _, r, term, trunc, info = env.step(a)
        c = cost * np.mean(np.clip(a.astype(np.float64), -1, 1) ** 2)
        if version(any_id) == "v1":
            want = min(max(math.exp(-info["abs_phi_sf"] / sigma) - c, 0.0), 1.0)
        else:
            want = min(max(-info["abs_phi"] / scale - c, -(clip or 100.0)), 0.0)
        assert r == pytest.approx(want, rel=1e-12, abs=1e-300)
        if term or trunc:
            env.reset()


def test_reciprocal_reward_is_the_documented_long_tail(env_cache) -> None:
    """``reward="reciprocal"``: ``clip(1 / (1 + |phi~| / sigma) - c mean(a^2), 0, 1)``, which is
    never below the exponential's ``exp(-|phi~| / sigma)`` (``1 + x <= e^x``) and, unlike it, still
    tells far states apart (it falls as ``sigma / |phi~|``)."""
    for name in ("flocking", "usv", "cartpole"):
        env = env_cache(make_env_id(name), reward="reciprocal", action_cost=0.1)
        sigma = type(task(env)).reward_sigma
        env.reset(seed=3)
        for a in action_seq(env, 60, lo=-1.5, hi=1.5):
            _, r, term, trunc, info = env.step(a)
            c = 0.1 * np.mean(np.clip(a.astype(np.float64), -1, 1) ** 2)
            x = info["abs_phi_sf"] / sigma
            assert r == pytest.approx(min(max(1.0 / (1.0 + x) - c, 0.0), 1.0), rel=1e-12, abs=1e-300)
            assert r >= min(max(math.exp(-x) - c, 0.0), 1.0)
            if term or trunc:
                env.reset()


def test_rewards_stay_in_the_documented_range(id_scenario: tuple[str, str]) -> None:
    """Random, zero and law policies on every scenario: -v1 rewards in [0, 1], -v0 in
    [-reward_clip, 0]; observations finite and inside the space (a native vector env of 4 runs
    each policy; it equals single envs, see test_vector.py)."""
    any_id, scenario = id_scenario
    for policy_cls in (GeometricController, ZeroPolicy, RandomPolicy):
        venv = gym.make_vec(any_id, num_envs=4, vectorization_mode="vector_entry_point", scenario=scenario,
                            max_episode_steps=100)
        lo, hi = reward_range(any_id, venv)
        policy = policy_cls(venv)
        obs, _ = venv.reset(seed=11)
        rewards = []
        for _ in range(150):
            obs, r, term, trunc, _ = venv.step(policy.predict(obs)[0])
            assert obs.dtype == np.float32 and venv.observation_space.contains(obs)
            rewards.append(r)
        rewards = np.array(rewards)
        assert rewards.dtype == np.float64 and np.all(np.isfinite(rewards))
        assert lo <= rewards.min() and rewards.max() <= hi, policy_cls.__name__
        venv.close()


def test_law_earns_more_than_zero_and_random_actions(v1_id: str) -> None:
    """The geometric law, the baseline that solves the task, beats doing nothing and acting at
    random on the nominal scenario by a wide margin (mean reward per step)."""
    means = {}
    for policy_cls in (GeometricController, ZeroPolicy, RandomPolicy):
        venv = gym.make_vec(v1_id, num_envs=4, vectorization_mode="vector_entry_point")
        policy = policy_cls(venv)
        obs, _ = venv.reset(seed=5)
        total = 0.0
        for _ in range(200):
            obs, r, _, _, _ = venv.step(policy.predict(obs)[0])
            total += r.mean()
        means[policy_cls.__name__] = total / 200
    assert means["GeometricController"] > 0.8
    assert means["GeometricController"] > max(means["ZeroPolicy"], means["RandomPolicy"]) + 0.3, means


def test_termination_is_never_better_than_staying(v1_id: str) -> None:
    """An episode that is terminated (here: its state overflows at step 40) earns what its twin,
    which goes on, earned up to then, 0 at the termination, and nothing afterwards; every -v1
    reward is >= 0, so the twin that stays ends with more."""
    law_env, env = gym.make(v1_id), gym.make(v1_id)
    law = GeometricController(law_env)
    obs, _ = law_env.reset(seed=4)
    env.reset(seed=4)
    stay, ended = [], []
    for k in range(200):
        a = law.predict(obs)[0]
        obs, r, term, trunc, _ = law_env.step(a)
        assert not (term or trunc)
        stay.append(r)
        if len(ended) < 41:
            if k == 40:
                poke_velocities(env, 1e308)
            _, r_ended, term_ended, _, info = env.step(a)
            ended.append(r_ended)
            assert term_ended == (k == 40)
    assert info["termination_reason"] == "non_finite_state"
    assert ended[:40] == stay[:40] and ended[40] == 0.0
    assert min(stay) >= 0.0
    assert sum(ended) < sum(stay)


@needs_usv
@pytest.mark.parametrize("v", ["v1", "v0"])
def test_usv_leaving_a_small_domain_earns_less_than_staying_in_a_large_one(v: str) -> None:
    """Full-scale actions of alternating sign (+1, -1, ...) make the boat leave a 5 m square; a twin
    in the default 100 m square with the same actions earns exactly the same rewards up to then
    (the domain enters only the status and the observed position), and under the law it keeps
    earning afterwards: leaving is never rewarded.  Under -v0's raw reward (<= 0) it is the other
    way round, which is why -v1 bounds the reward in [0, 1]."""
    usv = f"vnhc_gym/USVStream-{v}"
    small, big = gym.make(usv, domain=5.0), gym.make(usv)
    law = GeometricController(big)
    small.reset(seed=3)
    obs, _ = big.reset(seed=3)
    r_small, r_big = [], []
    for k in range(400):
        a = np.array([(-1.0) ** k], np.float32)
        _, r, term, _, info = small.step(a)
        r_small.append(r)
        obs, r, term_big, _, _ = big.step(a)
        r_big.append(r)
        assert r_big[-1] == r_small[-1] and not term_big
        if term:
            break
    assert info["termination_reason"] == "out_of_domain" and 10 < len(r_small) < 300
    for _ in range(len(r_big), 400):
        obs, r, term_big, trunc, _ = big.step(law.predict(obs)[0])
        r_big.append(r)
        assert not term_big
    assert trunc and len(r_big) == 400
    if v == "v1":
        assert sum(r_big) > sum(r_small) + 50.0
    else:
        assert sum(r_big) < sum(r_small)


# --------------------------------------------------------------------------- episode ends


def test_time_limit_truncates_at_400_steps(any_id: str, env_cache) -> None:
    env = env_cache(any_id)
    law = GeometricController(env)
    obs, _ = env.reset(seed=0)
    for k in range(1, 401):
        obs, _, term, trunc, info = env.step(law.predict(obs)[0])
        assert not term
        assert trunc == (k == 400)
    assert info["time"] == pytest.approx(400 * 0.05, rel=1e-12)


def test_overflowing_state_ends_the_episode_with_a_finite_observation(any_id: str) -> None:
    """A state whose next RK4 step overflows ends the episode with ``non_finite_state``: the
    observation is finite and inside the space, the reward is the worst one (0 for -v1,
    -reward_clip for -v0), and the next reset starts a normal episode."""
    env = gym.make(any_id)
    env.reset(seed=0)
    poke_velocities(env, 1e308)
    with np.errstate(all="raise"):  # nothing on the Python side may overflow either
        obs, r, term, trunc, info = env.step(np.full(env.action_space.shape, 0.5, np.float32))
    assert term and not trunc and info["termination_reason"] == "non_finite_state"
    assert np.all(np.isfinite(obs)) and env.observation_space.contains(obs)
    assert r == reward_range(any_id, env)[0]
    obs, info = env.reset()
    assert env.observation_space.contains(obs) and np.all(np.isfinite(info["state"]))
    assert np.all(np.abs(info["state"]) < 1e6)


def test_huge_forces_and_steps_never_give_non_finite_outputs(any_id: str) -> None:
    """The largest accepted forces (1e12 N x 1e6) held for 1e6 s per step: every observation stays
    finite and in the space, every reward in range; the episode either goes on with a finite state
    or terminates for one of the task's reasons."""
    env = gym.make(any_id, force_bound=1e12, force_bound_scale=1e6, dt=1e6)
    lo, hi = reward_range(any_id, env)
    obs, _ = env.reset(seed=1)
    for a in np.sign(action_seq(env, 30, lo=-1, hi=1)):
        last = obs
        with np.errstate(all="raise"):
            obs, r, term, trunc, info = env.step(a)
        assert np.all(np.isfinite(obs)) and env.observation_space.contains(obs)
        assert lo <= r <= hi
        if term:
            assert info["termination_reason"] in task(env).all_reasons[1:]
            if info["termination_reason"] == "non_finite_state":  # the last finite observation, the worst reward
                np.testing.assert_array_equal(obs, last)
                assert r == lo
            break
        assert np.all(np.isfinite(info["state"]))


@needs_usv
@pytest.mark.parametrize("v", ["v0", "v1"])
def test_usv_huge_force_and_time_step_overflow_cleanly(v: str) -> None:
    """1e18 N held for 1e6 s spins the boat past anything it can observe, or out of its domain, in
    the first step; a non-finite end keeps the last finite observation."""
    env = gym.make(f"vnhc_gym/USVStream-{v}", force_bound=1e12, force_bound_scale=1e6, dt=1e6)
    obs0, _ = env.reset(seed=0)
    with np.errstate(all="raise"):
        obs, r, term, trunc, info = env.step(np.ones(1, np.float32))
    assert term and not trunc and info["termination_reason"] in ("non_finite_state", "out_of_domain")
    assert np.all(np.isfinite(obs)) and env.observation_space.contains(obs)
    if info["termination_reason"] == "non_finite_state":
        np.testing.assert_array_equal(obs, obs0)
        assert r == (0.0 if v == "v1" else -100.0)


@needs_flocking
@pytest.mark.parametrize("v", ["v0", "v1"])
def test_flocking_tiny_masses_overflow_cleanly(v: str) -> None:
    """u / m overflows in the first RK4 stage: the last finite observation is returned."""
    env = gym.make(f"vnhc_gym/FlockingAlign-{v}", masses=1e-308)
    obs0, _ = env.reset(seed=0)
    with np.errstate(all="raise"):
        obs, r, term, _, info = env.step(np.full(3, 0.5, np.float32))
    assert term and info["termination_reason"] == "non_finite_state"
    np.testing.assert_array_equal(obs, obs0)
    assert r == (0.0 if v == "v1" else -100.0)  # the card: info["state"] shows the overflow


@needs_usv
def test_usv_leaving_the_domain_terminates() -> None:
    env = gym.make(USV, preset="paper-northeast", domain=1.2)
    env.reset(seed=0)  # starts at (1, 1), drifting north-east at ~1 m/s
    for k in range(1, 200):  # noqa: B007 (k used after the loop)
        obs, r, term, trunc, info = env.step(np.zeros(1, np.float32))
        x, y = info["state"][:2]
        assert term == (abs(x) > 1.2 or abs(y) > 1.2)
        if term:
            break
    assert term and info["termination_reason"] == "out_of_domain" and 1 < k < 200
    assert env.observation_space.contains(obs) and 0.0 <= r <= 1.0


@needs_usv
@pytest.mark.parametrize("feedback", ["open", "continuous", "sampled"])
def test_usv_spinning_faster_than_the_turn_rate_limit_terminates(feedback: str) -> None:
    """In every feedback mode of the step (the action alone, or the law inside the integrator on top
    of it): each runs its own compiled kernel, and each must apply the task's state limits."""
    env = gym.make(USV, max_turn_rate=2.0, force_bound=1000.0)
    env.unwrapped.batch.set_feedback(feedback, 5.0)
    env.reset(seed=0)
    for _ in range(50):
        _, r, term, _, info = env.step(np.ones(1, np.float32))  # I thetadd = u = 1000 N: spins up
        if term:
            break
    assert term and info["termination_reason"] == "turn_rate_exceeded"
    assert abs(info["state"][5]) > 2.0 and math.isfinite(r)


# --------------------------------------------------------------------------- determinism and copies


def test_same_seed_gives_the_same_trajectory(id_scenario: tuple[str, str], assert_same) -> None:
    any_id, scenario = id_scenario
    env = gym.make(any_id, scenario=scenario, max_episode_steps=70)
    actions = action_seq(env, 160)
    a = rollout(env, 7, actions)
    b = rollout(gym.make(any_id, scenario=scenario, max_episode_steps=70), 7, actions, meddle=True)
    assert_same(a, b)
    c = rollout(env, 8, actions[:1])
    assert not np.array_equal(a[0][1]["state"], c[0][1]["state"])  # another seed, another start


def test_unseeded_resets_continue_the_seeded_stream(any_id: str, assert_same) -> None:
    env, twin = gym.make(any_id, scenario="noisy"), gym.make(any_id, scenario="noisy")
    assert_same(env.reset(seed=21), twin.reset(seed=21))
    first = env.reset()
    assert_same(first, twin.reset())
    assert not np.array_equal(first[1]["state"], env.reset(seed=21)[1]["state"])
    # Without any seed, every environment draws its own episodes (operating-system entropy).
    starts = {gym.make(any_id).reset()[1]["state"].tobytes() for _ in range(3)}
    assert len(starts) == 3


@pytest.mark.parametrize("scen", ["noisy", "disturbance", "mismatch"])
@pytest.mark.parametrize("how", ["pickle", "deepcopy"])
def test_copies_mid_episode_continue_identically(v1_id: str, scen: str, how: str, assert_same) -> None:
    """A copy taken mid-episode steps exactly like the original, through the time limit and a
    reset that draws the next episode from the copied random stream (the reward's version does not
    enter a copy: -v1 ids only)."""
    env = gym.make(v1_id, scenario=scen, max_episode_steps=50)
    actions = action_seq(env, 140, seed=5)
    env.reset(seed=11)
    for a in actions[:20]:
        env.step(a)
    clone = pickle.loads(pickle.dumps(env)) if how == "pickle" else copy.deepcopy(env)
    ends = 0
    for a in actions[20:]:
        out = env.step(a)
        assert_same(out, clone.step(a))
        if out[2] or out[3]:
            ends += 1
            assert_same(env.reset(), clone.reset())
    assert ends >= 2


def test_returned_arrays_are_not_views_of_the_state(any_id: str, assert_same) -> None:
    env, twin = gym.make(any_id), gym.make(any_id)
    obs, info = env.reset(seed=3)
    twin.reset(seed=3)
    for a in action_seq(env, 12):
        obs[:] = 1.0
        for key in ("phi", "state", "force"):
            info[key][:] = 1e6
        out = env.step(a)
        assert_same(out, twin.step(a))
        obs, info = out[0], out[4]


# --------------------------------------------------------------------------- bad input


def bad_actions(m: int) -> list[tuple[str, Any]]:
    return [("too long", np.zeros(m + 1)), ("batched", np.zeros((1, m))), ("scalar", np.float64(0.2)),
            ("empty", np.zeros(0)), ("list too long", [0.1] * (m + 2)), ("None", None),
            ("complex", np.zeros(m, np.complex128)), ("object", np.array([None] * m)), ("string", "abc"),
            ("datetime", np.zeros(m, "datetime64[s]")),
            ("nan", np.full(m, np.nan, np.float32)), ("inf", np.full(m, np.inf)), ("-inf", [-np.inf] * m),
            ("one nan", np.array([0.1] * (m - 1) + [np.nan])), ("10**400", 10**400), ("[10**400]", [10**400] * m)]


def test_bad_actions_raise_value_error_and_change_nothing(any_id: str, assert_same) -> None:
    env, twin = gym.make(any_id, scenario="noisy"), gym.make(any_id, scenario="noisy")
    env.reset(seed=1)
    twin.reset(seed=1)
    m = env.action_space.shape[0]
    good = action_seq(env, 3)
    for _, bad in bad_actions(m):
        with pytest.raises(ValueError, match=r"\baction\b"):
            env.step(bad)
        with pytest.raises(ValueError, match=r"\baction\b"):
            env.unwrapped.step(bad)
    for a in good:  # nothing above touched the episode or its random stream
        assert_same(env.step(a), twin.step(a))


def test_other_action_types_act_like_clipped_float64(any_id: str, assert_same) -> None:
    env, twin = gym.make(any_id), gym.make(any_id)
    env.reset(seed=2)
    twin.reset(seed=2)
    m = env.action_space.shape[0]
    a = np.full(m, 0.5)
    rng = np.random.default_rng(0)
    others = [a.astype(np.float32), a.astype(np.float16), a.astype(">f8"), a.tolist(), tuple(a),
              np.ones(m, np.int64), np.full(m, -1e300), rng.choice([-1e30, -5.0, -1.0000001, 0.3, 1.5, 1e30], m),
              np.full((m, 2), 0.25)[:, 0]]
    for other in others:
        want = np.clip(np.asarray(other, dtype=np.float64), -1.0, 1.0)
        assert_same(env.step(other), twin.step(want))


def _bad_kwargs() -> list[Any]:
    """(id, keyword arguments, the argument the message must name, expected exception types)."""
    common: list[tuple[dict, str, tuple]] = [
        ({"bogus_keyword": 1}, "bogus_keyword", (ValueError,)),
        ({"scenario": []}, "scenario", (ValueError,)),
        ({"scenario": "windy"}, "scenario", (ValueError,)),
        ({"reward": "shaped"}, "reward", (ValueError,)),
        ({"obs_clip": 1e39}, "obs_clip", (ValueError,)),
        ({"obs_clip": np.nan}, "obs_clip", (ValueError,)),
        ({"force_bound": 10**31}, "force_bound", (ValueError,)),
        ({"force_bound": 10**400}, "force_bound", (ValueError,)),
        ({"force_bound": -1.0}, "force_bound", (ValueError,)),
        ({"dt": None}, "dt", (TypeError,)),
        ({"dt": 0.0}, "dt", (ValueError,)),
        ({"substeps": 2.0}, "substeps", (TypeError,)),
        ({"param_mismatch": 1.0}, "param_mismatch", (ValueError,)),
        ({"impulse_prob": 1.5}, "impulse_prob", (ValueError,)),
    ]
    #: Bad values of task options, used for every task that has the option.
    options: dict[str, list[Any]] = {
        "preset": [{}, "nope"], "current": [np.array([1.0]), "gulfstream"], "masses": ["abc", [2.0, 2.0]],
        "current_params": [{"c1": "x"}, 5], "mass": ["abc", 0.0], "inertia": [np.inf], "n_agents": ["3", 1],
        "g": [-10.0], "domain": [0.0], "max_turn_rate": [np.nan], "offset": [{}], "cruise_speed": [-1.0],
        "max_speed": ["fast"],
    }
    cases = []
    for env_id in env_ids(None):
        opts = task_of_env_id(env_id).task_class.Options.defaults()
        rows = list(common)
        rows += [({name: value}, name, (ValueError, TypeError)) for name, values in options.items() if name in opts
                 for value in values]
        if "current" in opts:
            rows.append(({"current": "northeast", "current_params": {"c1": "x"}}, "current_params", (TypeError,)))
        for kwargs, name, exc in rows:
            value = repr(next(iter(kwargs.values())))[:20]
            cases.append(pytest.param(env_id, kwargs, name, exc, id=f"{env_id[9:]}-{name}={value}"))
    return cases


@pytest.mark.parametrize("env_id, kwargs, name, exc", _bad_kwargs())
def test_bad_keyword_arguments_raise_naming_the_argument(env_id: str, kwargs: dict, name: str, exc: tuple) -> None:
    with pytest.raises(exc, match=re.escape(name)):
        gym.make(env_id, **kwargs)


def test_force_bound_of_10_to_the_30_is_refused(any_id: str) -> None:
    with pytest.raises(ValueError, match="force_bound"):
        gym.make(any_id, force_bound=10**30)


def test_bad_render_mode_raises_naming_it(any_id: str) -> None:
    entry = task_of_env_id(any_id)
    env_cls = getattr(entry.load(), f"{entry.env_name}Env")
    for bad in ([], "ansi"):
        with pytest.raises(ValueError, match="render_mode"):
            env_cls(render_mode=bad)


# --------------------------------------------------------------------------- scenarios


def test_saturated_scenario_scales_the_force_bound(any_id: str) -> None:
    env, nominal = gym.make(any_id, scenario="saturated"), gym.make(any_id)
    bound = task(env).force_bound
    np.testing.assert_array_equal(bound, task(nominal).force_bound * 0.05)
    env.reset(seed=0)
    m = env.action_space.shape[0]
    for a in (np.full(m, 7.0, np.float32), np.full(m, -0.5, np.float32), np.linspace(-3, 3, m).astype(np.float32)):
        info = env.step(a)[4]
        np.testing.assert_allclose(info["force"], np.clip(a.astype(np.float64), -1, 1) * bound, rtol=1e-15)


def test_coarse_scenario_uses_0_1_s_and_4_substeps(any_id: str) -> None:
    env = gym.make(any_id, scenario="coarse")
    assert env.unwrapped.dt == 0.1 and env.unwrapped.config.substeps == 4
    env.reset(seed=0)
    assert env.step(np.zeros(env.action_space.shape, np.float32))[4]["time"] == 0.1
    assert gym.make(any_id, scenario="coarse", dt=0.02).unwrapped.dt == 0.02  # explicit arguments win


def test_mismatch_scenario_draws_true_parameters_per_episode(any_id: str) -> None:
    """The task's uncertain parameters are the nominal ones times U(0.7, 1.3), new every episode and
    reproducible by seed; the others, and everything in the nominal scenario, stay nominal."""
    env = gym.make(any_id, scenario="mismatch")
    t = task(env)
    names = t.model.param_names
    perturbed = [names.index(p) for p in t.uncertain]
    others = [i for i in range(len(names)) if i not in perturbed]
    assert perturbed
    seen = []
    for seed in (0, 1, 2, None, None):
        true = env.reset(seed=seed)[1]["params"]
        nominal = env.unwrapped.batch.buf.params_nominal[0]
        ratio = true[perturbed] / nominal[perturbed]
        assert np.all(ratio != 1.0) and np.all(np.abs(ratio - 1.0) <= 0.3)
        np.testing.assert_array_equal(true[others], nominal[others])
        seen.append(true[perturbed].tobytes())
    assert len(set(seen)) == len(seen)
    assert env.reset(seed=0)[1]["params"][perturbed].tobytes() == seen[0]
    plain = gym.make(any_id)
    np.testing.assert_array_equal(plain.reset(seed=0)[1]["params"], plain.unwrapped.batch.buf.params_nominal[0])


def test_noisy_scenario_adds_gaussian_noise_to_observations_only(any_id: str) -> None:
    noisy, clean = gym.make(any_id, scenario="noisy"), gym.make(any_id, scenario="noisy", obs_noise=0.0)
    o1, _ = noisy.reset(seed=5)
    o2, _ = clean.reset(seed=5)
    diffs = []
    for k, a in enumerate(action_seq(noisy, 300)):
        inside = np.abs(o2) < 9.5  # away from the clip bounds
        diffs.append(np.where(inside, o1.astype(np.float64) - o2, np.nan))
        o1, _, t1, tr1, i1 = noisy.step(a)
        o2, _, t2, _, i2 = clean.step(a)
        np.testing.assert_array_equal(i1["state"], i2["state"])  # the noise is only in what is observed
        assert t1 == t2
        if t1 or tr1:
            o1, _ = noisy.reset(seed=100 + k)
            o2, _ = clean.reset(seed=100 + k)
    d = np.array(diffs)
    d = d[np.isfinite(d)]
    assert d.size > 1000
    assert np.std(d) == pytest.approx(0.02, rel=0.1)
    assert abs(np.mean(d)) < 0.02 * 5 / math.sqrt(d.size)
    assert np.mean(d == 0) < 0.01


def test_disturbance_scenario_kicks_velocities(any_id: str) -> None:
    """Kicks (the difference to an undisturbed twin stepped from the same state) hit the velocities
    the task's impulse mask names, in about impulse_prob = 5 % of the steps, with std impulse_scale;
    positions and the other velocities never move."""
    env, twin = gym.make(any_id, scenario="disturbance"), gym.make(any_id)
    cfg = env.unwrapped.batch.params
    mask = np.asarray(env.unwrapped.task.impulse_mask)
    n = mask.shape[0]
    env.reset(seed=9)
    twin.reset(seed=9)
    kicks = []
    steps = 2000
    zero = np.zeros(env.action_space.shape, np.float32)
    buf, tbuf = env.unwrapped.batch.buf, twin.unwrapped.batch.buf
    for k in range(steps):
        for name in ("state", "params_true", "params_nominal"):  # the undisturbed step from the same point
            getattr(tbuf, name)[0] = getattr(buf, name)[0]
        _, _, term, trunc, info = env.step(zero)
        _, _, _, _, tinfo = twin.step(zero)
        kick = info["state"] - tinfo["state"]
        if np.any(kick != 0):
            kicks.append(kick)
        if term or trunc:
            env.reset(seed=1000 + k)
    kicks = np.array(kicks)
    assert 0.03 * steps <= len(kicks) <= 0.07 * steps
    moved = np.r_[np.zeros(n, bool), mask != 0]
    assert np.all(kicks[:, ~moved] == 0)
    scaled = kicks[:, moved] / mask[mask != 0]
    assert np.std(scaled) == pytest.approx(cfg.impulse_scale, rel=0.15)
    assert gym.make(any_id).unwrapped.batch.params.impulse_prob == 0.0 and cfg.impulse_prob == 0.05


def test_episodes_start_off_the_constraint(any_id: str, env_cache) -> None:
    """The cards: every component of phi starts away from zero (there is something to do)."""
    env = env_cache(any_id)
    for seed in range(100):
        _, info = env.reset(seed=seed)
        assert np.all(np.abs(info["phi"]) > 0.05) and info["abs_phi_sf"] > 0.05, seed
        assert np.all(np.isfinite(info["state"]))


# --------------------------------------------------------------------------- physics


@pytest.mark.parametrize("gain", [1.0, 3.0])
def test_continuous_feedback_makes_phi_decay_like_exp_minus_k_t(v1_id: str, gain: float) -> None:
    """The law evaluated at every RK4 stage gives phi' = -k phi: |phi(t)| = exp(-k t) |phi(0)| (to
    RK4 accuracy, within 2 %), down to a few percent of its start after 4 / k seconds."""
    env = gym.make(v1_id)
    env.unwrapped.batch.set_feedback("continuous", gain)
    _, info = env.reset(seed=3)
    phi0 = np.abs(info["phi"])
    dt = env.unwrapped.dt
    zero = np.zeros(env.action_space.shape, np.float32)
    steps = int(round(4.0 / gain / dt))
    for k in range(1, steps + 1):
        _, _, term, _, info = env.step(zero)
        assert not term
        if k % max(steps // 8, 1) == 0:
            ratio = np.abs(info["phi"]) / (phi0 * math.exp(-gain * k * dt))
            np.testing.assert_allclose(ratio, 1.0, atol=0.02, err_msg=f"t = {k * dt:.2f} s")
    assert np.all(np.abs(info["phi"]) < 0.05 * phi0)
    # Open loop again: phi no longer decays like that.
    env.unwrapped.batch.set_feedback("open")
    _, info = env.reset(seed=3)
    for _ in range(steps):
        info = env.step(zero)[4]
    assert not np.all(np.abs(info["phi"]) < 0.05 * phi0)


def test_sampled_feedback_also_stabilises(v1_id: str) -> None:
    """The law evaluated once per control period (held over it) drives |phi| below 5 % in 2 s at k = 2."""
    env = gym.make(v1_id)
    env.unwrapped.batch.set_feedback("sampled", 2.0)
    _, info = env.reset(seed=8)
    phi0 = np.abs(info["phi"])
    for _ in range(40):
        info = env.step(np.zeros(env.action_space.shape, np.float32))[4]
    assert np.all(np.abs(info["phi"]) < 0.05 * phi0)


@needs_flocking
@pytest.mark.parametrize("scen", ["nominal", "mismatch"])
def test_flocking_moves_by_its_equations_with_the_true_masses(scen: str) -> None:
    """m_b xdd_b = u_b, m_b zdd_b = u_b - m_b g, leader free fall: constant accelerations, which
    RK4 integrates exactly, so one step changes the velocities by (u/m, u/m - g) dt."""
    env = gym.make(FLOCK, scenario=scen)
    g, bound = 10.0, 250.0
    for seed in range(4):
        _, info = env.reset(seed=seed)
        m = info["params"][:4]
        for a in action_seq(env, 10, seed=seed, lo=-1, hi=1):
            s0 = info["state"]
            _, _, _, _, info = env.step(a)
            u = a.astype(np.float64) * bound
            dv = info["state"][8:] - s0[8:]
            np.testing.assert_allclose(dv[:3], u / m[:3] * 0.05, rtol=1e-9, atol=1e-12)
            np.testing.assert_allclose(dv[4:7], (u / m[:3] - g) * 0.05, rtol=1e-9, atol=1e-12)
            assert dv[3] == 0.0 and dv[7] == pytest.approx(-g * 0.05, rel=1e-12)


@needs_usv
@pytest.mark.parametrize("scen", ["nominal", "mismatch"])
def test_usv_turns_by_its_equation_with_the_true_inertia(scen: str) -> None:
    """I thetadd = u (the current does not turn the boat): thetad changes by u dt / I exactly."""
    env = gym.make(USV, scenario=scen)
    names = task(env).model.param_names
    for seed in range(4):
        _, info = env.reset(seed=seed)
        inertia = info["params"][names.index("I")]
        for a in action_seq(env, 10, seed=seed, lo=-1, hi=1):
            thd0 = info["state"][5]
            _, _, term, _, info = env.step(a)
            assert info["state"][5] - thd0 == pytest.approx(float(a[0]) * 100.0 * 0.05 / inertia, rel=1e-9, abs=1e-13)
            if term:
                break


#: The original paper's initial states: flocking positions (10,56), (30,100), (50,100), (10,90) and
#: velocities (0.5,1), (1,1), (-1,-1), (0.6,0) laid out (x1..x4, z1..z4, xd1..xd4, zd1..zd4); USV
#: q0 = (1, 1, pi/2) with qd0 = (0.8, 0.5, 0) (north-east) or (1, 1, 0) (anticyclone).  phi(0) from
#: the constraints' formulas: (0.6, 0.6, -0.6), 0.8 - 1 = -0.2 and 0 (on the manifold).
PAPER = {
    ("flocking", "paper"): ([10, 30, 50, 10, 56, 100, 100, 90, 0.5, 1, -1, 0.6, 1, 1, -1, 0], [0.6, 0.6, -0.6]),
    ("usv", "paper-northeast"): ([1, 1, np.pi / 2, 0.8, 0.5, 0], [-0.2]),
    ("usv", "paper-anticyclone"): ([1, 1, np.pi / 2, 1, 1, 0], [0.0]),
}


@pytest.mark.parametrize("name, preset", [pytest.param(n, p, marks=pytest.mark.skipif(
    n not in TASKS, reason=f"{n} is not registered")) for n, p in PAPER])
def test_preset_resets_to_the_paper_state(name: str, preset: str) -> None:
    state, phi = PAPER[(name, preset)]
    env = gym.make(vnhc_gym.env_id(name), preset=preset)
    for seed in (0, 1, None, 12345):
        _, info = env.reset(seed=seed)
        np.testing.assert_array_equal(info["state"], np.array(state, dtype=np.float64))
        np.testing.assert_allclose(info["phi"], phi, atol=1e-12)
        for a in action_seq(env, 5, seed=seed or 0):
            env.step(a)


# --------------------------------------------------------------------------- rendering


def test_rgb_array_rendering(v1_id: str) -> None:
    pytest.importorskip("pygame")
    env = gym.make(v1_id, render_mode="rgb_array")
    env.reset(seed=0)
    first = env.render()
    for a in action_seq(env, 60):
        if env.step(a)[2]:
            break
    frame = env.render()
    for f in (first, frame):
        assert isinstance(f, np.ndarray) and f.dtype == np.uint8 and f.ndim == 3 and f.shape[2] == 3
        assert f.shape[0] >= 100 and f.shape[1] >= 100
        assert len(np.unique(f.reshape(-1, 3), axis=0)) > 5  # something is drawn
    assert first.shape == frame.shape and not np.array_equal(first, frame)
    poke_velocities(env, 1e300)  # a non-finite step still renders
    assert env.step(np.zeros(env.action_space.shape, np.float32))[2]
    assert env.render().shape == first.shape
    env.close()
    env.close()  # closing twice is fine


def test_human_rendering_returns_none_and_no_mode_warns(v1_id: str) -> None:
    pytest.importorskip("pygame")
    env = gym.make(v1_id, render_mode="human")
    env.reset(seed=0)
    assert env.render() is None
    env.step(np.zeros(env.action_space.shape, np.float32))
    env.close()
    plain = gym.make(v1_id).unwrapped
    plain.reset(seed=0)
    with pytest.warns(UserWarning, match="render_mode"):
        assert plain.render() is None


def test_scenarios_are_documented_in_every_card(v1_id: str) -> None:
    entry = task_of_env_id(v1_id)
    card = inspect.getdoc(getattr(entry.load(), f"{entry.env_name}Env")) or ""
    for name in SCENARIOS:
        assert name in card, name
    for option in entry.task_class.Options.defaults():
        assert f"``{option}``" in card, option
