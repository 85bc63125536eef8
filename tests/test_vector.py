"""Native vector environments against Gymnasium's ``SyncVectorEnv`` of single ones, and the SB3 adapter.

``gym.make_vec(id, num_envs=N, vectorization_mode="vector_entry_point", **kw)`` must equal
``SyncVectorEnv([lambda: gym.make(id, **kw)] * N)`` bit for bit (observations, rewards, flags,
every info key and mask) in every autoreset mode, through truncations, terminations and resets;
the ids come from the registry (``conftest.py``).
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.error import ResetNeeded
from gymnasium.vector import AutoresetMode, SyncVectorEnv
from gymnasium.vector.utils import batch_space

import vnhc_gym
from vnhc_gym.baselines import GeometricController
from vnhc_gym.tasks import TASKS, task_of_env_id

pytestmark = pytest.mark.filterwarnings("ignore:.*is out of date:DeprecationWarning")

N = 3
MODES = [AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP, AutoresetMode.DISABLED]
mode_param = pytest.mark.parametrize("mode", MODES, ids=lambda m: m.value)


def native(env_id: str, n: int = N, **kwargs: Any) -> gym.vector.VectorEnv:
    return gym.make_vec(env_id, num_envs=n, vectorization_mode="vector_entry_point", **kwargs)


def sync(env_id: str, n: int = N, mode: AutoresetMode = AutoresetMode.NEXT_STEP, **kwargs: Any) -> SyncVectorEnv:
    return SyncVectorEnv([lambda: gym.make(env_id, **kwargs)] * n, autoreset_mode=mode)


def actions(env: gym.vector.VectorEnv, steps: int, seed: int = 0, scale: float = 1.3) -> np.ndarray:
    """Random actions, partly out of range (the envs clip them)."""
    shape = (steps, env.num_envs, *env.single_action_space.shape)
    return np.random.default_rng(seed).uniform(-scale, scale, size=shape).astype(np.float32)


def poke(env: gym.Env, row: int) -> None:
    """Every velocity of a row's state to 1e308: its next RK4 step overflows (``non_finite_state``)."""
    buf = env.unwrapped.batch.buf
    buf.state[row, buf.state.shape[1] // 2:] = 1e308


def run_both(vec: gym.vector.VectorEnv, ref: SyncVectorEnv, steps: int, assert_same, *, seed: int = 123,
             scale: float = 1.3, pokes: dict[int, list[int]] | None = None) -> dict[str, np.ndarray]:
    """Reset both with ``seed``, step both with the same random actions, compare every output; in
    DISABLED mode reset the finished sub-envs of both (and, once, a sub-env that is not finished).
    ``pokes``: step -> rows whose state overflows at that step (in both).  Returns the number of
    truncations, terminations and ``non_finite_state`` terminations per sub-env."""
    mode = vec.metadata["autoreset_mode"]
    assert mode is ref.metadata["autoreset_mode"]
    assert_same(vec.reset(seed=seed), ref.reset(seed=seed))
    count = {k: np.zeros(vec.num_envs, int) for k in ("truncated", "terminated", "non_finite")}
    for t, a in enumerate(actions(vec, steps, seed, scale)):
        for row in (pokes or {}).get(t, []):
            poke(vec, row)
            poke(ref.envs[row], 0)
        out, want = vec.step(a), ref.step(a)
        assert_same(out, want)
        count["terminated"] += out[2]
        count["truncated"] += out[3]
        info = out[4]["final_info"] if mode is AutoresetMode.SAME_STEP and out[2].any() else out[4]
        count["non_finite"] += out[2] & (info.get("termination_reason", np.full(vec.num_envs, None))
                                         == "non_finite_state")
        if mode is AutoresetMode.DISABLED:
            done = out[2] | out[3]
            if t == 7:
                done = done.copy()
                done[0] = True  # a partial reset of a sub-env that may not be finished
            if done.any():
                assert_same(vec.reset(options={"reset_mask": done}), ref.reset(options={"reset_mask": done.copy()}))
    return count


# --------------------------------------------------------------------------- construction


def test_make_vec_builds_the_native_class(any_id: str) -> None:
    entry = task_of_env_id(any_id)
    env = native(any_id, 4, scenario="coarse")
    assert type(env) is getattr(entry.load(), f"{entry.env_name}VectorEnv")
    assert env.num_envs == 4 and env.max_episode_steps == vnhc_gym.MAX_EPISODE_STEPS
    assert env.metadata["autoreset_mode"] is AutoresetMode.NEXT_STEP
    single = gym.make(any_id, scenario="coarse")
    assert env.single_observation_space == single.observation_space
    assert env.single_action_space == single.action_space
    assert env.observation_space == batch_space(single.observation_space, 4)
    assert env.action_space == batch_space(single.action_space, 4)
    assert env.dt == single.unwrapped.dt == 0.1 and env.config.reward == single.unwrapped.config.reward
    obs, _ = env.reset(seed=0)
    assert obs.dtype == np.float32 and obs.shape == env.observation_space.shape
    same = native(any_id, 2, autoreset_mode="SameStep", max_episode_steps=5)
    assert same.metadata["autoreset_mode"] is AutoresetMode.SAME_STEP and same.max_episode_steps == 5
    same.reset(seed=0)
    for k in range(1, 6):
        assert same.step(np.zeros(same.action_space.shape, np.float32))[3].all() == (k == 5)


@pytest.mark.parametrize("kwargs, name", [
    ({"num_envs": 0}, "num_envs"), ({"max_episode_steps": 0}, "max_episode_steps"),
    ({"autoreset_mode": "Sometimes"}, "autoreset_mode"), ({"scenario": []}, "scenario"),
    ({"scenario": "bogus"}, "scenario"), ({"dt": -1.0}, "dt"), ({"nonsense": 1}, "nonsense"),
    ({"obs_clip": 1e39}, "obs_clip"), ({"force_bound": 10**31}, "force_bound"), ({"render_mode": []}, "render_mode"),
])
def test_bad_constructor_arguments_raise_naming_them(v1_id: str, kwargs: dict, name: str) -> None:
    kw = {"num_envs": 2, **kwargs}
    with pytest.raises(ValueError, match=name):
        gym.make_vec(v1_id, vectorization_mode="vector_entry_point", **kw)


# --------------------------------------------------------------------------- vector == sync


@mode_param
def test_vector_equals_sync_of_single_envs(v1_id: str, scenario: str, mode: AutoresetMode, assert_same) -> None:
    kw = {"scenario": scenario, "max_episode_steps": 25}
    vec, ref = native(v1_id, autoreset_mode=mode, **kw), sync(v1_id, mode=mode, **kw)
    assert vec.observation_space == ref.observation_space and vec.action_space == ref.action_space
    count = run_both(vec, ref, 120, assert_same)
    assert (count["truncated"] + count["terminated"]).min() >= 3  # every sub-env ended and reset several times


@mode_param
def test_vector_equals_sync_for_v0(v0_id: str, mode: AutoresetMode, assert_same) -> None:
    kw = {"scenario": "disturbance", "max_episode_steps": 25}
    count = run_both(native(v0_id, autoreset_mode=mode, **kw), sync(v0_id, mode=mode, **kw), 80, assert_same)
    assert (count["truncated"] + count["terminated"]).min() >= 2


@mode_param
def test_vector_equals_sync_through_terminations(v1_id: str, mode: AutoresetMode, assert_same) -> None:
    """Sub-envs whose state overflows end with ``non_finite_state`` (the info reports the
    overflowing state) while their neighbours go on, as single envs do."""
    kw = {"scenario": "noisy", "max_episode_steps": 40}
    vec, ref = native(v1_id, autoreset_mode=mode, **kw), sync(v1_id, mode=mode, **kw)
    count = run_both(vec, ref, 60, assert_same, pokes={5: [0, 2], 9: [1], 30: [0, 1, 2]}, scale=1.0)
    assert count["non_finite"].tolist() == [2, 2, 2]


@pytest.mark.skipif("usv" not in TASKS, reason="the USV task is not registered")
@mode_param
def test_usv_vector_equals_sync_when_boats_leave_a_small_domain(mode: AutoresetMode, assert_same) -> None:
    """Terminations of the physics itself: random large actions in a 5 m square."""
    usv = vnhc_gym.env_id("usv")
    kw = {"domain": 5.0, "max_episode_steps": 60}
    count = run_both(native(usv, autoreset_mode=mode, **kw), sync(usv, mode=mode, **kw), 120, assert_same, scale=3.0)
    assert count["terminated"].sum() >= 6 and count["non_finite"].sum() == 0


def test_vector_equals_sync_with_other_settings(v1_id: str, assert_same) -> None:
    """Reward, bound and clip settings reach every row (here in SAME_STEP mode, 5 sub-envs)."""
    kw = {"action_cost": 0.3, "reward_sigma": 0.5, "force_bound": 30.0, "obs_clip": 2.0, "substeps": 2,
          "max_episode_steps": 17, "scenario": "mismatch"}
    vec = native(v1_id, 5, autoreset_mode=AutoresetMode.SAME_STEP, **kw)
    run_both(vec, sync(v1_id, 5, AutoresetMode.SAME_STEP, **kw), 60, assert_same, seed=9)


# --------------------------------------------------------------------------- autoreset details


def test_disabled_mode_needs_explicit_resets(v1_id: str) -> None:
    env = native(v1_id, 2, autoreset_mode=AutoresetMode.DISABLED, max_episode_steps=1)
    env.reset(seed=0)
    a = np.zeros(env.action_space.shape, np.float32)
    assert env.step(a)[3].all()
    with pytest.raises(RuntimeError, match="DISABLED"):
        env.step(a)
    for bad, exc in ((np.array([True, False]).astype(int), TypeError), (np.array([True]), ValueError),
                     (np.array([False, False]), ValueError), ([True, True], TypeError)):
        with pytest.raises(exc, match="reset_mask"):
            env.reset(options={"reset_mask": bad})
    env.reset(options={"reset_mask": np.array([True, True])})
    assert not env.step(a)[2].any()


def test_next_step_ignores_actions_of_resetting_sub_envs(v1_id: str, assert_same) -> None:
    """As in SyncVectorEnv, a sub-env that resets this step ignores its action (even a NaN one)
    and reports reward 0: a finished episode collects nothing more."""
    vec, ref = native(v1_id, 2, max_episode_steps=2), sync(v1_id, 2, max_episode_steps=2)
    assert_same(vec.reset(seed=0), ref.reset(seed=0))
    a = np.full(vec.action_space.shape, 0.3, dtype=np.float32)
    for _ in range(2):
        assert_same(vec.step(a), ref.step(a))
    a[1] = np.nan  # both sub-envs reset now
    out = vec.step(a)
    assert_same(out, ref.step(a))
    np.testing.assert_array_equal(out[1], [0.0, 0.0])
    assert "params" in out[4] and out[4]["_params"].all()
    with pytest.raises(ValueError, match="actions"):
        vec.step(a)


# --------------------------------------------------------------------------- bad input, seeding, attributes


def test_bad_actions_raise_and_change_nothing(v1_id: str) -> None:
    env = native(v1_id, 4, scenario="noisy")
    m = env.single_action_space.shape[0]
    with pytest.raises(ResetNeeded):
        env.step(np.zeros((4, m)))
    env.reset(seed=3)
    env.step(np.full((4, m), 0.5))
    buf = env.unwrapped.batch.buf
    before = {name: np.copy(getattr(buf, name)) for name in buf._fields}
    for bad in (np.zeros((5, m)), np.zeros((4, m + 1)), np.zeros(m), np.zeros((2, 2, m)), 10**400,
                np.zeros((4, m), np.complex128), [[None] * m] * 4):
        with pytest.raises(ValueError, match="actions"):
            env.step(bad)
    for value in (np.nan, np.inf, -np.inf):
        a = np.zeros((4, m), dtype=np.float32)
        a[2, 0] = value
        with pytest.raises(ValueError, match="actions"):
            env.step(a)
        with pytest.raises(ValueError, match="actions"):
            env.step(a.astype(np.float64).tolist())
    for name, value in before.items():
        np.testing.assert_array_equal(getattr(buf, name), value, err_msg=name)
    # Out of range is clipped; lists, integers and other float types are accepted.
    bound = env.task.force_bound
    env.step(np.full((4, m), 7, dtype=np.int64))
    np.testing.assert_array_equal(buf.force_applied, np.broadcast_to(bound, (4, m)))
    env.step([[-3.0] * m] * 4)
    np.testing.assert_array_equal(buf.force_applied, np.broadcast_to(-bound, (4, m)))
    for a in (np.full((4, m), 0.5, np.float16), np.full((4, m), 0.5, ">f8"), np.full((4, 2 * m), 0.5)[:, ::2]):
        env.step(a)
        np.testing.assert_array_equal(buf.force_applied, np.broadcast_to(0.5 * bound, (4, m)))


def test_seeding_and_attributes(v1_id: str) -> None:
    env = native(v1_id, 3, scenario="mismatch")
    env.reset(seed=10)
    assert env.np_random_seed == (10, 11, 12)
    obs1 = env.reset(seed=[5, None, 7])[0]
    assert env.np_random_seed == (5, 11, 7)
    single = gym.make(v1_id, scenario="mismatch")
    np.testing.assert_array_equal(obs1[0], single.reset(seed=5)[0])
    np.testing.assert_array_equal(obs1[2], single.reset(seed=7)[0])
    with pytest.raises(ValueError, match="length"):
        env.reset(seed=[1, 2])
    for bad in (-1, [1, -2, 3], [1.5, None, None]):
        with pytest.raises(gym.error.Error, match="Seed"):  # the single env's rule and message
            env.reset(seed=bad)
    env.reset()  # seed None keeps the generators
    assert env.np_random_seed == (5, 11, 7)
    assert env.get_attr("scenario") == ("mismatch",) * 3
    assert env.get_attr("np_random_seed") == (5, 11, 7)
    env.set_attr("scenario", ["x", "x", "x"])
    assert env.scenario == "x"
    with pytest.raises(ValueError, match="share"):
        env.set_attr("scenario", ["a", "b", "c"])


def test_returned_arrays_are_never_overwritten_while_held(v1_id: str) -> None:
    env = native(v1_id, 4, max_episode_steps=2)
    env.reset(seed=0)
    a = np.full(env.action_space.shape, 0.4, dtype=np.float32)
    kept = [env.step(a) for _ in range(3)]
    assert "params" in kept[2][4]  # step 3 resets every sub-env (NEXT_STEP)
    snapshot = [(o.copy(), {k: np.copy(v) for k, v in info.items()}) for o, _, _, _, info in kept]
    for _ in range(6):
        env.step(a)
    for (o, _, _, _, info), (o0, info0) in zip(kept, snapshot, strict=True):
        np.testing.assert_array_equal(o, o0)
        for k, v in info0.items():
            np.testing.assert_array_equal(info[k], v)


def test_continuous_feedback_acts_on_every_row(v1_id: str) -> None:
    """``batch.set_feedback`` runs the law in all sub-envs: |phi| decays like exp(-k t) in each."""
    env = native(v1_id, 3)
    env.unwrapped.batch.set_feedback("continuous", 2.0)
    _, info = env.reset(seed=1)
    phi0 = np.abs(info["phi"])
    for _ in range(20):  # 1 s
        _, _, _, _, info = env.step(np.zeros(env.action_space.shape, np.float32))
    np.testing.assert_allclose(np.abs(info["phi"]) / phi0, np.exp(-2.0), rtol=0.02)


# --------------------------------------------------------------------------- rendering


def test_render_gives_one_frame_per_sub_env(v1_id: str) -> None:
    pytest.importorskip("pygame")
    vec = native(v1_id, 2, render_mode="rgb_array")
    vec.reset(seed=4)
    frames = vec.render()
    assert isinstance(frames, tuple) and len(frames) == 2
    assert not np.array_equal(frames[0], frames[1])
    for i, frame in enumerate(frames):
        assert frame.dtype == np.uint8 and frame.ndim == 3 and frame.shape[2] == 3
        single = gym.make(v1_id, render_mode="rgb_array")
        single.reset(seed=4 + i)
        np.testing.assert_array_equal(frame, single.render())
        single.close()
    vec.close()


# --------------------------------------------------------------------------- Stable-Baselines3


def _dummy(env_id: str, n: int, **kwargs: Any):
    from stable_baselines3.common.vec_env import DummyVecEnv

    return DummyVecEnv([lambda: gym.make(env_id, **kwargs)] * n)


def test_sb3_vec_env_meets_sb3_expectations(v1_id: str) -> None:
    from stable_baselines3.common.vec_env import VecEnv, VecMonitor

    n, length = 3, 20
    venv = vnhc_gym.make_sb3_vec_env(v1_id, n_envs=n, seed=0, max_episode_steps=length)
    assert isinstance(venv, VecEnv) and isinstance(venv, VecMonitor) and venv.num_envs == n
    single = gym.make(v1_id)
    assert venv.observation_space == single.observation_space and venv.action_space == single.action_space
    obs = venv.reset()
    d = single.observation_space.shape[0]
    assert obs.shape == (n, d) and obs.dtype == np.float32
    reset_infos = venv.venv.reset_infos  # the adapter's (SB3's VecMonitor keeps its own, empty ones)
    assert len(reset_infos) == n and all("params" in i for i in reset_infos)
    law = GeometricController(single)
    returns = np.zeros(n)
    for k in range(1, 2 * length + 1):
        a = law.predict(obs)[0]
        prev = obs
        obs, rew, dones, infos = venv.step(a)
        assert obs.shape == (n, d) and obs.dtype == np.float32 and all(venv.observation_space.contains(o) for o in obs)
        assert rew.shape == (n,) and rew.dtype == np.float32 and np.all((rew >= 0) & (rew <= 1))
        assert dones.shape == (n,) and dones.dtype == bool
        assert isinstance(infos, list) and len(infos) == n and all("phi" in i for i in infos)
        returns += rew
        assert dones.any() == dones.all() == (k % length == 0)  # the time limit: the law never terminates
        for i in np.flatnonzero(dones):
            term_obs = infos[i]["terminal_observation"]
            assert term_obs.shape == (d,) and term_obs.dtype == np.float32
            assert infos[i]["TimeLimit.truncated"] is True
            assert not np.array_equal(obs[i], term_obs)  # the returned observation starts the next episode
            assert infos[i]["episode"]["l"] == length
            assert infos[i]["episode"]["r"] == pytest.approx(returns[i], rel=1e-5)
            returns[i] = 0.0
        assert prev is not obs
    venv.close()


def test_sb3_seeding_is_reproducible(v1_id: str, assert_same) -> None:
    runs = []
    for seed in (7, 7, 8):
        venv = vnhc_gym.make_sb3_vec_env(v1_id, n_envs=2, seed=seed, monitor=False, scenario="noisy")
        out = [venv.reset()]
        for a in actions(venv.venv, 15, seed=1):
            out.append(venv.step(a)[:3])
        runs.append(out)
        venv.seed(seed)  # seed() again: the next reset starts the same episodes
        np.testing.assert_array_equal(venv.reset(), out[0])
    assert_same(runs[0], runs[1])
    assert not np.array_equal(runs[0][0], runs[2][0])


@pytest.mark.parametrize("mode", [AutoresetMode.SAME_STEP, AutoresetMode.NEXT_STEP], ids=lambda m: m.value)
def test_sb3_adapter_equals_dummy_vec_env(v1_id: str, mode: AutoresetMode, assert_same) -> None:
    """The adapter over a native vector env of either autoreset mode behaves like SB3's own
    DummyVecEnv of single envs: observations, float32 rewards, dones, infos with
    ``terminal_observation`` and ``TimeLimit.truncated``, reset infos."""
    from vnhc_gym.sb3 import GymnasiumVecEnvAdapter

    n, kw = 3, {"scenario": "disturbance", "max_episode_steps": 15}
    ref = _dummy(v1_id, n, **kw)
    ada = GymnasiumVecEnvAdapter(native(v1_id, n, autoreset_mode=mode, **kw))
    assert ada.seed(7) == ref.seed(7)
    assert_same(ada.reset(), ref.reset())
    assert_same(ada.reset_infos, ref.reset_infos)
    ends = 0
    for a in actions(ada.venv, 50, seed=2):
        out, want = ada.step(a), ref.step(a)
        assert_same(out, want)
        assert_same(ada.reset_infos, ref.reset_infos)
        ends += int(want[2].sum())
    assert ends >= 3 * n
    ada.close()
    ref.close()


def test_sb3_evaluate_policy_with_the_law(v1_id: str) -> None:
    """SB3's evaluate_policy runs a baseline (SB3's ``predict``) on the adapter and reads the
    episode returns from VecMonitor: the law earns close to one per step."""
    from stable_baselines3.common.evaluation import evaluate_policy

    venv = vnhc_gym.make_sb3_vec_env(v1_id, n_envs=2, seed=3, max_episode_steps=100)
    law = GeometricController(gym.make(v1_id))
    returns, lengths = evaluate_policy(law, venv, n_eval_episodes=4, return_episode_rewards=True)
    assert lengths == [100] * 4
    assert all(80.0 < r <= 100.0 for r in returns), returns
