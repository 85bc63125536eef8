"""Native vector envs and the SB3 adapter against Gymnasium's / SB3's loops over single envs."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.error import ResetNeeded
from gymnasium.utils.env_checker import data_equivalence
from gymnasium.vector import AutoresetMode, SyncVectorEnv

import vnhc_gym
from vnhc_gym.envs.task import SCENARIOS
from vnhc_gym.envs.vector import FlockingAlignVectorEnv, USVStreamVectorEnv

FLOCK, USV = vnhc_gym.ENV_IDS
VECTOR_CLS = {FLOCK: FlockingAlignVectorEnv, USV: USVStreamVectorEnv}
MODES = (AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP)
SEED = 123
N = 3

# Extra keyword arguments beyond the scenarios: presets, other currents / systems, reward
# settings, and a small USV domain that makes boats leave it (terminations).
EXTRA_KWARGS = {
    FLOCK: [{"preset": "paper"}, {"n_agents": 3, "masses": [1.0, 2.0, 3.0], "g": 9.81},
            {"action_cost": 0.1, "phi_scale": 2.0, "reward_clip": 5.0, "force_bound": 30.0, "obs_clip": 2.0}],
    USV: [{"preset": "paper-northeast"}, {"current": "vortex"}, {"current": "shear", "current_params": {"s": 0.5}},
          {"domain": 5.5, "scenario": "disturbance", "impulse_scale": 2.0}, {"max_turn_rate": 1.0},
          {"scenario": "mismatch", "mass": 5.0, "inertia": 0.7, "action_cost": 0.2}],
}
CASES = [(env_id, {"scenario": s}) for env_id in (FLOCK, USV) for s in SCENARIOS] + [
    (env_id, kw) for env_id in (FLOCK, USV) for kw in EXTRA_KWARGS[env_id]]


def _case_id(case: tuple[str, dict]) -> str:
    env_id, kw = case
    return env_id.split("/")[1].split("-")[0] + "-" + "-".join(f"{k}={v}" for k, v in kw.items())


def _sync(env_id: str, n: int, mode: AutoresetMode, **kwargs) -> SyncVectorEnv:
    return SyncVectorEnv([lambda: gym.make(env_id, **kwargs) for _ in range(n)], autoreset_mode=mode)


def _actions(rng: np.random.Generator, steps: int, n: int, m: int) -> np.ndarray:
    """Random actions, partly out of range (the envs clip them)."""
    return rng.uniform(-1.3, 1.3, size=(steps, n, m)).astype(np.float32)


def _assert_same_run(vec: gym.vector.VectorEnv, ref: gym.vector.VectorEnv, steps: int, seed: int = SEED,
                     min_resets: int = 2) -> None:
    """Reset both with ``seed``, step both with the same actions, compare every output exactly."""
    obs_a, info_a = vec.reset(seed=seed)
    obs_b, info_b = ref.reset(seed=seed)
    assert data_equivalence(obs_a, obs_b, exact=True)
    assert data_equivalence(info_a, info_b, exact=True), (info_a, info_b)
    n = vec.num_envs
    acts = _actions(np.random.default_rng(seed), steps, n, vec.single_action_space.shape[0])
    ends = np.zeros(n, dtype=int)
    for t in range(steps):
        out_a = vec.step(acts[t])
        out_b = ref.step(acts[t])
        for name, a, b in zip(("obs", "reward", "terminated", "truncated"), out_a[:4], out_b[:4], strict=True):
            assert a.dtype == b.dtype and a.shape == b.shape, (t, name, a.dtype, b.dtype)
            np.testing.assert_array_equal(a, b, err_msg=f"step {t}: {name}")
        np.testing.assert_array_equal(out_a[4]["phi"], out_b[4]["phi"], err_msg=f"step {t}: info phi")
        assert data_equivalence(out_a[4], out_b[4], exact=True), (t, out_a[4], out_b[4])
        ends += out_a[2] | out_a[3]
    assert ends.min() >= min_resets, f"each sub-env should end >= {min_resets} episodes, got {ends}"


@pytest.mark.parametrize("mode", MODES, ids=lambda m: m.value)
@pytest.mark.parametrize("case", CASES, ids=_case_id)
def test_vector_equals_sync_of_single_envs(case: tuple[str, dict], mode: AutoresetMode) -> None:
    env_id, kwargs = case
    vec = VECTOR_CLS[env_id](N, max_episode_steps=30, autoreset_mode=mode, **kwargs)
    ref = _sync(env_id, N, mode, max_episode_steps=30, **kwargs)
    assert vec.metadata["autoreset_mode"] is mode
    assert vec.single_observation_space == ref.single_observation_space
    assert vec.single_action_space == ref.single_action_space
    assert vec.observation_space == ref.observation_space and vec.action_space == ref.action_space
    _assert_same_run(vec, ref, steps=100)


@pytest.mark.parametrize("env_id,scenario,length", [(FLOCK, "noisy", 255), (USV, "disturbance", 270)])
def test_vector_equals_sync_over_long_random_episodes(env_id: str, scenario: str, length: int) -> None:
    """Noise and impulses are drawn every step from each sub-env's stream; the (discarded) step
    of a sub-env that NEXT_STEP-resets must draw nothing, or every later episode would differ."""
    vec = VECTOR_CLS[env_id](2, max_episode_steps=length, scenario=scenario)
    ref = _sync(env_id, 2, AutoresetMode.NEXT_STEP, max_episode_steps=length, scenario=scenario)
    _assert_same_run(vec, ref, steps=2 * length + 20, min_resets=2)


@pytest.mark.parametrize("threaded", [True, False], ids=["fused-threaded", "serial"])
@pytest.mark.parametrize("env_id", [FLOCK, USV])
def test_parallel_kernel_batch_equals_sync(env_id: str, threaded: bool) -> None:
    """A batch large enough for the threaded kernel (>= PARALLEL_MIN_ROWS) gives the same numbers,
    on the fused threaded step (envs/_fused.py) and on the serial one it falls back to."""
    from vnhc_gym.envs.task import PARALLEL_MIN_ROWS

    n = PARALLEL_MIN_ROWS + 7
    vec = VECTOR_CLS[env_id](n, max_episode_steps=12)
    vec.task._threaded = threaded
    vec.task._next_probe = 10**9  # no timing probe: this path only
    ref = _sync(env_id, n, AutoresetMode.NEXT_STEP, max_episode_steps=12)
    _assert_same_run(vec, ref, steps=27, seed=5)


@pytest.mark.parametrize("threaded", [True, False], ids=["fused-threaded", "serial"])
@pytest.mark.parametrize("n", [N, 263], ids=["small", "big"])
def test_rows_that_overflow_in_rk4_equal_single_envs(n: int, threaded: bool) -> None:
    """Sub-envs whose RK4 step overflows end with ``non_finite_state`` and report the non-finite
    state in ``info["state"]`` (the single env's documented behaviour), while their neighbours go
    on; the step writes its result straight into the info buffer, so this is the branch to check."""
    vec = VECTOR_CLS[USV](n, max_episode_steps=50)
    vec.task._threaded = threaded
    vec.task._next_probe = 10**9
    ref = _sync(USV, n, AutoresetMode.NEXT_STEP, max_episode_steps=50)
    vec.reset(seed=7)
    ref.reset(seed=7)
    bad = [1, n - 1]
    for i in bad:  # xd, thetad: x + dt xd stays finite, the current terms overflow
        for task, row in ((vec.task, i), (ref.envs[i].unwrapped.task, 0)):
            task.state[row, 3] = task.state[row, 5] = 1e308
    acts = _actions(np.random.default_rng(0), 4, n, 1)
    for t in range(4):
        out_a, out_b = vec.step(acts[t]), ref.step(acts[t])
        for a, b in zip(out_a[:4], out_b[:4], strict=True):
            np.testing.assert_array_equal(a, b, err_msg=f"step {t}")
        assert out_a[4].keys() == out_b[4].keys()
        for key in out_a[4]:  # NaN-aware (data_equivalence compares with ==)
            np.testing.assert_array_equal(out_a[4][key], out_b[4][key], err_msg=f"step {t}: {key}")
        if t == 0:
            assert list(np.flatnonzero(out_a[2])) == bad
            assert all(out_a[4]["termination_reason"][i] == "non_finite_state" for i in bad)
            assert not np.all(np.isfinite(out_a[4]["state"][bad])) and np.all(np.isfinite(vec.task.state))
            np.testing.assert_array_equal(vec.task.next_state[bad], out_a[4]["state"][bad])


def test_thread_pool_settings_stay_out_of_the_environment() -> None:
    """The libgomp settings of the thread pool's start are not left in ``os.environ``."""
    import os

    from vnhc_gym.envs.task import _OMP_ENV, PARALLEL_MIN_ROWS

    before = {k: os.environ.get(k) for k in _OMP_ENV}
    VECTOR_CLS[FLOCK](PARALLEL_MIN_ROWS).reset(seed=0)
    assert {k: os.environ.get(k) for k in _OMP_ENV} == before


def test_disabled_mode_with_reset_mask_equals_sync() -> None:
    vec = FlockingAlignVectorEnv(N, max_episode_steps=7, autoreset_mode="Disabled", scenario="noisy")
    ref = _sync(FLOCK, N, AutoresetMode.DISABLED, max_episode_steps=7, scenario="noisy")
    obs_a, _ = vec.reset(seed=1)
    obs_b, _ = ref.reset(seed=1)
    acts = _actions(np.random.default_rng(0), 40, N, 3)
    mask_toggle = np.array([True, False, True])
    for t in range(40):
        out_a, out_b = vec.step(acts[t]), ref.step(acts[t])
        assert data_equivalence(out_a, out_b, exact=True), t
        done = out_a[2] | out_a[3]
        if t == 3:  # a partial reset of sub-envs that are not done
            done = done | mask_toggle
        if done.any():
            ra = vec.reset(options={"reset_mask": done})
            rb = ref.reset(options={"reset_mask": done.copy()})
            assert data_equivalence(ra, rb, exact=True), t
    short = FlockingAlignVectorEnv(2, max_episode_steps=1, autoreset_mode=AutoresetMode.DISABLED)
    short.reset(seed=0)
    assert short.step(acts[0, :2])[3].all()
    with pytest.raises(RuntimeError, match="DISABLED"):
        short.step(acts[0, :2])


@pytest.mark.parametrize("env_id", [FLOCK, USV])
def test_make_vec_returns_native_class(env_id: str) -> None:
    env = gym.make_vec(env_id, num_envs=4, vectorization_mode="vector_entry_point", scenario="noisy")
    assert type(env) is VECTOR_CLS[env_id]
    assert env.num_envs == 4 and env.max_episode_steps == vnhc_gym.MAX_EPISODE_STEPS
    assert env.metadata["autoreset_mode"] is AutoresetMode.NEXT_STEP
    assert env.observation_space.shape == (4, *env.single_observation_space.shape)
    assert env.observation_space.dtype == np.float32 and env.action_space.shape == (4, *env.single_action_space.shape)
    obs, _ = env.reset(seed=0)
    assert obs.dtype == np.float32 and obs.shape == env.observation_space.shape
    # Default truncation: 400 steps, like gym.make.
    acts = np.zeros(env.action_space.shape, dtype=np.float32)
    for _ in range(vnhc_gym.MAX_EPISODE_STEPS - 1):
        assert not env.step(acts)[3].any()
    assert env.step(acts)[3].all()
    env.close()
    same = gym.make_vec(env_id, num_envs=2, vectorization_mode="vector_entry_point", autoreset_mode="SameStep",
                        max_episode_steps=5)
    assert same.metadata["autoreset_mode"] is AutoresetMode.SAME_STEP and same.max_episode_steps == 5


@pytest.mark.parametrize("kwargs,match", [({"scenario": "bogus"}, "scenario"), ({"dt": -1.0}, "dt"),
                                          ({"nonsense": 1}, "nonsense"), ({"num_envs": 0}, "num_envs"),
                                          ({"max_episode_steps": 0}, "max_episode_steps"),
                                          ({"autoreset_mode": "Sometimes"}, "autoreset_mode")])
def test_bad_constructor_arguments(kwargs: dict, match: str) -> None:
    kw = {"num_envs": 2, **kwargs}
    with pytest.raises(ValueError, match=match):
        FlockingAlignVectorEnv(**kw)


def _snapshot(env) -> dict:
    t = env.task
    return {"state": t.state.copy(), "obs32": t.obs32.copy(), "steps": t.steps.copy(), "force": t.force.copy(),
            "action": t.action.copy(), "autoreset": env._autoreset.copy(), "rng": t.rng.copy()}


@pytest.mark.parametrize("env_id", [FLOCK, USV])
def test_bad_actions_raise_and_change_nothing(env_id: str) -> None:
    env = VECTOR_CLS[env_id](4, scenario="noisy")
    m = env.single_action_space.shape[0]
    with pytest.raises(ResetNeeded):
        env.step(np.zeros((4, m)))
    env.reset(seed=3)
    env.step(np.full((4, m), 0.5))
    before = _snapshot(env)
    for bad in (np.zeros((5, m)), np.zeros((4, m + 1)), np.zeros(m), np.zeros((4,)), np.zeros((2, 2, m))):
        with pytest.raises(ValueError, match="shape"):
            env.step(bad)
    for value in (np.nan, np.inf, -np.inf):
        a = np.zeros((4, m), dtype=np.float32)
        a[2, 0] = value
        with pytest.raises(ValueError, match="finite"):
            env.step(a)
        with pytest.raises(ValueError, match="finite"):
            env.step(a.astype(np.float64).tolist())
    after = _snapshot(env)
    assert data_equivalence(before, after, exact=True)
    # Out of range is clipped; lists and integer arrays are accepted.
    env.step(np.full((4, m), 7, dtype=np.int64))
    np.testing.assert_array_equal(env.task.force, np.broadcast_to(env.task.force_bound, (4, m)))
    env.step([[-3.0] * m] * 4)
    np.testing.assert_array_equal(env.task.force, np.broadcast_to(-env.task.force_bound, (4, m)))
    for dtype in (np.float16, ">f8", np.int32):  # any dtype is converted before the compiled check
        env.step(np.full((4, m), 0.5 if dtype != np.int32 else 1).astype(dtype))
        np.testing.assert_array_equal(env.task.force[:, 0], env.task.force_bound[0] * (0.5 if dtype != np.int32 else 1))
    with pytest.raises(ValueError, match="real"):
        env.step(np.zeros((4, m), dtype=np.complex128))
    env.step(np.full((4, 2 * m), 0.25)[:, ::2])  # non-contiguous
    np.testing.assert_array_equal(env.task.force[:, 0], env.task.force_bound[0] * 0.25)


def test_next_step_ignores_actions_of_resetting_sub_envs() -> None:
    """As in SyncVectorEnv, a sub-env that resets this step ignores its action (even a NaN one)."""
    vec = FlockingAlignVectorEnv(2, max_episode_steps=2)
    ref = _sync(FLOCK, 2, AutoresetMode.NEXT_STEP, max_episode_steps=2)
    vec.reset(seed=0)
    ref.reset(seed=0)
    a = np.full((2, 3), 0.3, dtype=np.float32)
    for _ in range(2):
        assert data_equivalence(vec.step(a), ref.step(a), exact=True)
    a[1] = np.nan  # both sub-envs reset now
    assert data_equivalence(vec.step(a), ref.step(a), exact=True)
    with pytest.raises(ValueError, match="finite"):
        vec.step(a)


def test_seeding_and_attributes() -> None:
    env = USVStreamVectorEnv(3, scenario="mismatch")
    env.reset(seed=10)
    assert env.np_random_seed == (10, 11, 12)
    obs1 = env.reset(seed=[5, None, 7])[0]
    assert env.np_random_seed == (5, 11, 7)
    single = gym.make(USV, scenario="mismatch")
    np.testing.assert_array_equal(obs1[0], single.reset(seed=5)[0])
    np.testing.assert_array_equal(obs1[2], single.reset(seed=7)[0])
    with pytest.raises(ValueError, match="length"):
        env.reset(seed=[1, 2])
    for bad in (-1, [1, -2, 3], [1.5, None, None]):
        with pytest.raises(gym.error.Error, match="Seed"):  # the single env's rule and message
            env.reset(seed=bad)
    with pytest.raises(gym.error.Error, match="Seed"):
        single.reset(seed=-1)
    env.reset()  # seed None keeps the generators
    assert env.np_random_seed == (5, 11, 7)
    assert env.get_attr("scenario") == ("mismatch",) * 3
    assert env.get_attr("np_random_seed") == (5, 11, 7)
    assert env.call("get_attr", "render_mode")[0] == (None,) * 3
    env.set_attr("scenario", ["x", "x", "x"])
    assert env.scenario == "x"
    with pytest.raises(ValueError, match="share"):
        env.set_attr("scenario", ["a", "b", "c"])
    assert "USVStreamVectorEnv" in repr(env)


def test_render_rgb_array_matches_single_envs() -> None:
    pytest.importorskip("pygame")
    pytest.importorskip("vnhc_gym.envs.rendering")
    for env_id in (FLOCK, USV):
        vec = VECTOR_CLS[env_id](2, render_mode="rgb_array")
        vec.reset(seed=4)
        frames = vec.render()
        assert isinstance(frames, tuple) and len(frames) == 2
        for i in range(2):
            single = gym.make(env_id, render_mode="rgb_array")
            single.reset(seed=4 + i)
            np.testing.assert_array_equal(frames[i], single.render())
            single.close()
        vec.close()


# ---------------------------------------------------------------------------------------------- SB3
sb3 = pytest.importorskip("stable_baselines3")


def _dummy(env_id: str, n: int, **kwargs):
    from stable_baselines3.common.vec_env import DummyVecEnv

    return DummyVecEnv([lambda: gym.make(env_id, **kwargs) for _ in range(n)])


ADAPTER_BACKENDS = ["native-same-step", "native-next-step", "sync-next-step"]


def _adapter(backend: str, env_id: str, n: int, **kwargs):
    from vnhc_gym.sb3 import GymnasiumVecEnvAdapter

    if backend == "sync-next-step":
        return GymnasiumVecEnvAdapter(_sync(env_id, n, AutoresetMode.NEXT_STEP, **kwargs))
    mode = AutoresetMode.SAME_STEP if backend == "native-same-step" else AutoresetMode.NEXT_STEP
    return GymnasiumVecEnvAdapter(VECTOR_CLS[env_id](n, autoreset_mode=mode, **kwargs))


@pytest.mark.parametrize("backend", ADAPTER_BACKENDS)
@pytest.mark.parametrize("env_id,kwargs", [(FLOCK, {"scenario": "noisy"}), (USV, {"scenario": "disturbance"}),
                                           (USV, {"domain": 5.5})])
def test_sb3_adapter_equals_dummy_vec_env(backend: str, env_id: str, kwargs: dict) -> None:
    n, steps = 4, 100
    ref = _dummy(env_id, n, max_episode_steps=30, **kwargs)
    ada = _adapter(backend, env_id, n, max_episode_steps=30, **kwargs)
    assert ada.observation_space == ref.observation_space and ada.action_space == ref.action_space
    assert ada.seed(7) == ref.seed(7)
    obs_a, obs_b = ada.reset(), ref.reset()
    assert data_equivalence(obs_a, obs_b, exact=True)
    assert data_equivalence(ada.reset_infos, ref.reset_infos, exact=True)
    acts = _actions(np.random.default_rng(1), steps, n, ref.action_space.shape[0])
    ends = 0
    for t in range(steps):
        oa, ra, da, ia = ada.step(acts[t])
        ob, rb, db, ib = ref.step(acts[t])
        assert oa.dtype == ob.dtype == np.float32 and ra.dtype == rb.dtype == np.float32 and da.dtype == db.dtype
        np.testing.assert_array_equal(oa, ob, err_msg=f"step {t}: obs")
        np.testing.assert_array_equal(ra, rb, err_msg=f"step {t}: rewards")
        np.testing.assert_array_equal(da, db, err_msg=f"step {t}: dones")
        for i in np.flatnonzero(db):
            np.testing.assert_array_equal(ia[i]["terminal_observation"], ib[i]["terminal_observation"])
        assert data_equivalence(ia, ib, exact=True), (t, ia, ib)
        assert data_equivalence(ada.reset_infos, ref.reset_infos, exact=True), t
        ends += int(db.sum())
    assert ends >= 2 * n
    # Without a new seed(), reset() keeps every generator going (SB3 convention).
    assert data_equivalence(ada.reset(), ref.reset(), exact=True)
    assert ada.get_attr("render_mode") == ref.get_attr("render_mode") == [None] * n
    assert ada.env_is_wrapped(gym.Wrapper) == [backend.startswith("sync")] * n
    ada.close()
    ref.close()


def test_sb3_adapter_attribute_access() -> None:
    from vnhc_gym.sb3 import GymnasiumVecEnvAdapter

    ada = GymnasiumVecEnvAdapter(FlockingAlignVectorEnv(3, scenario="saturated"))
    assert ada.get_attr("scenario", indices=[0, 2]) == ["saturated"] * 2
    ada.set_attr("scenario", "custom")
    assert ada.get_attr("scenario") == ["custom"] * 3
    assert ada.env_method("get_attr", "scenario", indices=1) == [("custom",) * 3]
    with pytest.warns(UserWarning, match="render mode"):
        assert ada.get_images() == [None] * 3  # no render_mode: SB3 warns and returns None per env
    sync = GymnasiumVecEnvAdapter(_sync(FLOCK, 2, AutoresetMode.NEXT_STEP))
    sync.set_attr("extra", 5, indices=[1])
    assert sync.get_attr("extra", indices=[1]) == [5]
    assert sync.env_method("get_wrapper_attr", "extra", indices=[1]) == [5]


def test_make_sb3_vec_env_ppo_and_vecnormalize() -> None:
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecMonitor, VecNormalize

    from vnhc_gym.sb3 import GymnasiumVecEnvAdapter

    venv = vnhc_gym.make_sb3_vec_env(FLOCK, n_envs=8, seed=0, max_episode_steps=100)
    assert isinstance(venv, VecMonitor) and isinstance(venv.venv, GymnasiumVecEnvAdapter)
    assert type(venv.unwrapped.venv) is FlockingAlignVectorEnv and venv.num_envs == 8
    norm = VecNormalize(venv, norm_obs=True, norm_reward=True)
    model = PPO("MlpPolicy", norm, n_steps=256, batch_size=256, n_epochs=1, seed=0, device="cpu")
    model.learn(total_timesteps=2048)
    assert model.num_timesteps >= 2048
    assert len(model.ep_info_buffer) > 0  # VecMonitor reported finished episodes
    obs = norm.reset()
    assert obs.shape == (8, 12) and np.all(np.isfinite(obs))
    action, _ = model.predict(obs, deterministic=True)
    assert action.shape == (8, 3)
    norm.close()
    usv = VecNormalize(vnhc_gym.make_sb3_vec_env(USV, n_envs=2, seed=1, monitor=False, scenario="noisy"))
    usv.reset()
    for _ in range(5):
        obs, rew, done, info = usv.step(np.zeros((2, 1), dtype=np.float32))
    assert obs.shape == (2, 14) and rew.dtype == np.float32 and len(info) == 2
    # Ids without a vector entry point fall back to SyncVectorEnv.
    pend = vnhc_gym.make_sb3_vec_env("Pendulum-v1", n_envs=2, seed=0, monitor=False)
    assert pend.reset().shape == (2, 3)


# ---------------------------------------------------------------------------------------------- baseline
def test_geometric_baseline_batched_predict() -> None:
    baselines = pytest.importorskip("vnhc_gym.baselines")
    for env_id in (FLOCK, USV):
        env = VECTOR_CLS[env_id](5, scenario="nominal")
        ctrl = baselines.GeometricController(env)
        obs, info = env.reset(seed=2)
        start = info["abs_phi"].copy()
        for _ in range(40):
            actions, state = ctrl.predict(obs)
            assert state is None and actions.shape == (5, env.single_action_space.shape[0])
            rows = np.stack([ctrl.predict(o)[0] for o in obs])
            np.testing.assert_array_equal(actions, rows)
            obs, _, _, _, info = env.step(actions)
        assert np.all(info["abs_phi"] < start)  # the law drives phi towards 0


def test_returned_arrays_are_never_overwritten_while_held() -> None:
    """The vector env refills an earlier step's arrays only when nobody references them any more:
    observations, infos (the reset rows' ``params`` too) and views of them that a caller keeps
    stay as they were."""
    env = FlockingAlignVectorEnv(4, max_episode_steps=2)
    env.reset(seed=0)
    a = np.full((4, 3), 0.4, dtype=np.float32)
    kept = [env.step(a) for _ in range(3)]
    assert "params" in kept[2][4]  # step 3 resets every sub-env (NEXT_STEP)
    snapshot = [(o.copy(), {k: np.copy(v) for k, v in info.items()}) for o, _, _, _, info in kept]
    view = env.step(a)[4]["state"][2:, 1]
    view_before = view.copy()
    ids = set()
    for _ in range(12):  # results dropped at once: memory is reused (a handful of buffer sets)
        ids.add(id(env.step(a)[4]["phi"]))
    assert len(ids) <= 3
    for (o, _, _, _, info), (o0, info0) in zip(kept, snapshot, strict=True):
        np.testing.assert_array_equal(o, o0)
        for k, v in info0.items():
            np.testing.assert_array_equal(info[k], v)
    np.testing.assert_array_equal(view, view_before)
