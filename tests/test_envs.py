"""Acceptance tests of the Gymnasium environments ``FlockingAlign-v0`` and ``USVStream-v0``.

Expected values come from independent sources: the env docstrings (the behaviour spec), the
closed forms of NOTES.md typed out here in numpy, the paper's numbers, exact facts of RK4 (a
constant acceleration is integrated exactly) and twin environments that differ in one setting.
Nothing is compared with the code's own output pasted in.
"""

from __future__ import annotations

import copy
import math
import os
import pickle
import subprocess
import sys
import warnings
from functools import partial

os.environ["SDL_VIDEODRIVER"] = "dummy"  # before pygame initialises a display (human-mode checks)

import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402
from gymnasium.utils.env_checker import check_env as gym_check_env  # noqa: E402

import vnhc_gym  # noqa: E402
from vnhc_gym.envs import SCENARIOS  # noqa: E402
from vnhc_gym.mechanics import simulate  # noqa: E402
from vnhc_gym.systems import FLOCKING_PRESETS, USV_PRESETS, make_flocking, make_usv  # noqa: E402

FLOCK, USV = "vnhc_gym/FlockingAlign-v0", "vnhc_gym/USVStream-v0"
PRESETS = {FLOCK: ("paper",), USV: ("paper-northeast", "paper-anticyclone")}
SHORT = {FLOCK: "flock", USV: "usv"}
#: Docstring defaults: force bound (N), impulse std (m/s).
DEFAULT_BOUND = {FLOCK: 250.0, USV: 100.0}
DEFAULT_KICK = {FLOCK: 1.0, USV: 0.3}
G = 10.0

#: Every (env id, keyword arguments) the tests sweep: each scenario, and each preset.
CONFIGS = [pytest.param(e, {"scenario": s}, id=f"{SHORT[e]}-{s}") for e in vnhc_gym.ENV_IDS for s in SCENARIOS]
CONFIGS += [pytest.param(e, {"preset": p}, id=f"{SHORT[e]}-{p}") for e in vnhc_gym.ENV_IDS for p in PRESETS[e]]
#: The configurations whose episodes are random (a preset in the nominal scenario is deterministic).
RANDOM_CONFIGS = [c for c in CONFIGS if "scenario" in c.values[1]]



# --------------------------------------------------------------------------- helpers


def make(env_id: str, **kwargs) -> gym.Env:
    """The env as users get it (``gym.make``: TimeLimit, OrderEnforcing, PassiveEnvChecker)."""
    return gym.make(env_id, **kwargs)


def raw(env_id: str, **kwargs) -> gym.Env:
    return gym.make(env_id, **kwargs).unwrapped


def n_act(env_id: str) -> int:
    return 3 if env_id == FLOCK else 1


def action_seq(env_id: str, n: int, seed: int = 1234, lo: float = -1.2, hi: float = 1.2) -> np.ndarray:
    """Fixed actions, some outside [-1, 1] (exercises the clipping)."""
    return np.random.default_rng(seed).uniform(lo, hi, size=(n, n_act(env_id))).astype(np.float32)


def rollout(env: gym.Env, seed: int, actions: np.ndarray, meddle: bool = False):
    """Observations, rewards, info phis and done flags; resets (without seed) when done."""
    obs, info = env.reset(seed=seed)
    out_obs, rewards, phis, dones = [obs], [], [info["phi"]], []
    for k, a in enumerate(actions):
        if meddle:  # the global numpy RNG must play no part
            np.random.seed(k)  # noqa: NPY002
            np.random.rand(7)  # noqa: NPY002
        obs, r, term, trunc, info = env.step(a)
        out_obs.append(obs)
        rewards.append(r)
        phis.append(info["phi"])
        dones.append(term or trunc)
        if term or trunc:
            obs, info = env.reset()
            out_obs.append(obs)
            phis.append(info["phi"])
    return np.array(out_obs), np.array(rewards), np.array(phis), np.array(dones)


def flock_phi(s: np.ndarray, n: int = 4) -> np.ndarray:
    """NOTES.md: phi^b = xd_N zd_b - xd_b zd_N."""
    xd, zd = s[2 * n:3 * n], s[3 * n:4 * n]
    return xd[-1] * zd[:-1] - xd[:-1] * zd[-1]


def flock_law(s: np.ndarray, masses: np.ndarray, g: float = G, k: float = 1.0, n: int = 4) -> np.ndarray:
    """NOTES.md: u*_b = m_b [g (xd_N - xd_b) - k phi^b] / (xd_N - zd_N)."""
    xd, zd = s[2 * n:3 * n], s[3 * n:4 * n]
    return masses[:-1] * (g * (xd[-1] - xd[:-1]) - k * flock_phi(s, n)) / (xd[-1] - zd[-1])


def usv_phi(s: np.ndarray, c: tuple[float, float]) -> float:
    """NOTES.md: phi = sin(th) xd - cos(th) yd + cos(th) C2 - sin(th) C1."""
    _, _, th, xd, yd, _ = s
    return math.sin(th) * xd - math.cos(th) * yd + math.cos(th) * c[1] - math.sin(th) * c[0]


def usv_law(s: np.ndarray, c: tuple[float, float], m: float, k: float = 1.0) -> float:
    """NOTES.md: u* = -m [k phi + thetad (xd cos(th) + yd sin(th))]."""
    _, _, th, xd, yd, thd = s
    return -m * (k * usv_phi(s, c) + thd * (xd * math.cos(th) + yd * math.sin(th)))


def usv_current(env: gym.Env, x: float, y: float) -> tuple[float, float]:
    """The true current at (x, y) from the current library's numpy evaluation (not the compiled kernel)."""
    task = env.unwrapped.task
    scale = float(task.params_true[0, task.model.param_names.index("current_scale")])
    c = scale * task.field.value(x, y, task.current_params(0))
    return float(c[0]), float(c[1])


def same_step(r1, r2) -> None:
    """Two ``step`` results are identical (obs, reward, flags and every info entry)."""
    np.testing.assert_array_equal(r1[0], r2[0])
    assert r1[1:4] == r2[1:4]
    assert r1[4].keys() == r2[4].keys()
    for key in r1[4]:
        np.testing.assert_array_equal(r1[4][key], r2[4][key], err_msg=key)


# --------------------------------------------------------------------------- registration and API checkers


def test_registry_and_metadata():
    ids = {i for i in gym.registry if i.startswith("vnhc_gym/")}
    assert ids == set(vnhc_gym.ENV_IDS)
    for env_id in vnhc_gym.ENV_IDS:
        assert gym.registry[env_id].max_episode_steps == vnhc_gym.MAX_EPISODE_STEPS == 400
        env = make(env_id)
        assert env.metadata["render_fps"] > 0
        assert set(env.metadata["render_modes"]) == {"human", "rgb_array"}
        env.close()


@pytest.mark.filterwarnings("error")
@pytest.mark.parametrize("env_id, kwargs", CONFIGS)
def test_checkers(env_id, kwargs):
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    gym_check_env(raw(env_id, **kwargs))
    with warnings.catch_warnings():
        # Whitelist: Gymnasium always warns when check_env gets a wrapped env (here the gym.make stack,
        # which we want to check too); it is advice to prefer env.unwrapped, not a problem of the env.
        warnings.filterwarnings("ignore", message=r".*is different from the unwrapped version")
        gym_check_env(make(env_id, **kwargs))
    sb3_check_env(raw(env_id, **kwargs), warn=True)


@pytest.mark.parametrize("env_id", vnhc_gym.ENV_IDS)
def test_make_in_fresh_interpreter(env_id):
    code = (
        "import sys, numpy as np, gymnasium as gym\n"
        "assert 'vnhc_gym' not in sys.modules\n"
        f"env = gym.make('vnhc_gym:{env_id}')\n"
        "obs, info = env.reset(seed=0)\n"
        "obs, r, term, trunc, info = env.step(env.action_space.sample())\n"
        "assert env.observation_space.contains(obs) and np.isfinite(r)\n"
        "print('ok')\n"
    )
    env = {k: v for k, v in os.environ.items() if k != "PYTHONSTARTUP"}
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, env=env)
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == "ok"


def test_time_limit_truncates_at_400_steps():
    for env_id in vnhc_gym.ENV_IDS:
        env = make(env_id, preset=PRESETS[env_id][0])
        env.reset(seed=0)
        zero = np.zeros(n_act(env_id), np.float32)
        for k in range(1, 401):
            _, _, term, trunc, info = env.step(zero)
            assert not term
            assert trunc == (k == 400)
        assert info["time"] == pytest.approx(400 * 0.05)


# --------------------------------------------------------------------------- determinism


@pytest.mark.parametrize("env_id, kwargs", CONFIGS)
def test_seed_determinism(env_id, kwargs):
    actions = action_seq(env_id, 200)
    a = rollout(make(env_id, **kwargs), 7, actions)
    b = rollout(make(env_id, **kwargs), 7, actions, meddle=True)
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x, y)
    c = rollout(make(env_id, **kwargs), 8, actions)
    if "preset" in kwargs:  # the docstring: a preset resets to the paper's state every time
        np.testing.assert_array_equal(a[0], c[0])
    else:
        assert a[0].shape != c[0].shape or not np.array_equal(a[0], c[0])
        assert not np.array_equal(a[2][0], c[2][0])  # already the first episode's start differs


# --------------------------------------------------------------------------- many random steps


@pytest.mark.parametrize("env_id", vnhc_gym.ENV_IDS)
def test_random_steps_stay_finite_and_in_space(env_id):
    """>= 10^4 steps per env over every scenario: finite observations inside the space, rewards
    in [-reward_clip, 0], finite phi; termination only for a documented reason."""
    per_scenario = 1700
    total = 0
    for i, scenario in enumerate(SCENARIOS):
        env = make(env_id, scenario=scenario)
        space = env.observation_space
        env.action_space.seed(i)
        rng = np.random.default_rng(i)
        obs, info = env.reset(seed=100 + i)
        assert space.contains(obs)
        for _ in range(per_scenario):
            a = env.action_space.sample()
            if rng.random() < 0.05:  # now and then a far out-of-range action
                a = (a * 1e6).astype(np.float32)
            obs, r, term, trunc, info = env.step(a)
            total += 1
            assert obs.dtype == np.float32 and np.all(np.isfinite(obs)) and space.contains(obs)
            assert isinstance(r, float) and -100.0 <= r <= 0.0
            assert np.all(np.isfinite(info["phi"])) and np.isfinite(info["abs_phi"])
            assert info["abs_phi"] == pytest.approx(np.mean(np.abs(info["phi"])), rel=1e-12)
            if term:
                assert info["termination_reason"] in ("non_finite_state", "out_of_domain",
                                                     "turn_rate_exceeded")
            else:
                assert "termination_reason" not in info
            if term or trunc:
                obs, info = env.reset()
                assert space.contains(obs)
    assert total >= 10_000


@pytest.mark.parametrize("env_id, kwargs", CONFIGS)
def test_returned_arrays_are_not_views_of_the_state(env_id, kwargs):
    actions = action_seq(env_id, 12)
    env, twin = make(env_id, **kwargs), make(env_id, **kwargs)
    obs, info = env.reset(seed=3)
    twin.reset(seed=3)
    for a in actions:
        obs[:] = 1.0
        for key in ("phi", "state", "force"):
            info[key][:] = 1e6
        r, rt = env.step(a), twin.step(a)
        same_step(r, rt)
        obs, info = r[0], r[4]


# --------------------------------------------------------------------------- pickling, copying, processes


@pytest.mark.parametrize("env_id, kwargs", CONFIGS)
def test_pickle_and_deepcopy_continue_identically(env_id, kwargs):
    actions = action_seq(env_id, 330, seed=5)
    env = make(env_id, **kwargs)
    env.reset(seed=11)
    for a in actions[:20]:
        env.step(a)
    clones = [pickle.loads(pickle.dumps(env)), copy.deepcopy(env)]
    # 310 more steps cross the end of the pre-drawn noise / kick chunk (256 steps); a reset halfway
    # must draw the same next episode from the copied generator.
    for k, a in enumerate(actions[20:]):
        if k == 150:
            ref = env.reset()
            for c in clones:
                o, i = c.reset()
                np.testing.assert_array_equal(o, ref[0])
                np.testing.assert_array_equal(i["state"], ref[1]["state"])
        r = env.step(a)
        for c in clones:
            same_step(r, c.step(a))


def test_subproc_vec_env_spawn():
    """Both envs under SB3's SubprocVecEnv with the "spawn" start method (fresh interpreters that
    import everything by name) give exactly what the in-process DummyVecEnv gives."""
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv

    fns = {e: [partial(gym.make, f"vnhc_gym:{e}", scenario=s) for s in ("noisy", "disturbance")]
           for e in vnhc_gym.ENV_IDS}
    subs = {e: SubprocVecEnv(f, start_method="spawn") for e, f in fns.items()}  # all children start together
    try:
        for env_id, sub in subs.items():
            ref = DummyVecEnv(fns[env_id])
            sub.seed(21)
            ref.seed(21)
            np.testing.assert_array_equal(sub.reset(), ref.reset())
            for a in action_seq(env_id, 30).reshape(15, 2, -1):
                o1, r1, d1, _ = sub.step(a)
                o2, r2, d2, _ = ref.step(a)
                np.testing.assert_array_equal(o1, o2)
                np.testing.assert_array_equal(r1.astype(np.float32), r2)  # DummyVecEnv keeps rewards in float32
                np.testing.assert_array_equal(d1, d2)
            ref.close()
    finally:
        for sub in subs.values():
            sub.close()


# --------------------------------------------------------------------------- the geometric law vs the core


def test_flocking_law_policy_matches_core_sampled_simulation():
    n = 400
    env = raw(FLOCK, preset="paper", dt=0.01, substeps=1)
    bound = DEFAULT_BOUND[FLOCK]
    _, info = env.reset(seed=0)
    phis, states = [info["phi"]], [info["state"]]
    for _ in range(n):
        u = flock_law(info["state"], np.full(4, 2.0))
        a = u / bound
        assert np.all(np.abs(a) <= 1.0)
        _, _, term, _, info = env.step(a)
        assert not term
        phis.append(info["phi"])
        states.append(info["state"])
    traj = simulate(make_flocking(4), FLOCKING_PRESETS["paper"].state(), 0.01, n, feedback="sampled", gains=1.0)
    phis, states = np.array(phis), np.array(states)
    np.testing.assert_allclose(phis, traj.phi, rtol=1e-9, atol=1e-9 * np.abs(phis[0]).max())
    np.testing.assert_allclose(states, traj.states, rtol=1e-9, atol=1e-9 * np.abs(states[0]).max())
    # And the law does its job: |phi| fell by orders of magnitude in 4 s (exp(-4) ~ 0.018).
    assert np.abs(phis[-1]).max() < 0.05 * np.abs(phis[0]).max()


@pytest.mark.parametrize("preset", ["paper-northeast", "paper-anticyclone"])
def test_usv_law_policy_matches_core_sampled_simulation(preset):
    n = 400
    p = USV_PRESETS[preset]

    def current(x, y):  # NOTES.md: north-east C = (1, 1); anticyclone C = (y, -x + y)
        return (1.0, 1.0) if preset == "paper-northeast" else (y, -x + y)

    bound = 1e6
    env = raw(USV, preset=preset, dt=0.01, substeps=1, force_bound=bound)
    _, info = env.reset(seed=0)
    phis, states = [info["phi"]], [info["state"]]
    for _ in range(n):
        s = info["state"]
        a = np.array([usv_law(s, current(s[0], s[1]), p.m) / bound])
        _, _, term, _, info = env.step(a)
        assert not term
        phis.append(info["phi"])
        states.append(info["state"])
    traj = simulate(make_usv(p.current), p.state(), 0.01, n, feedback="sampled", gains=1.0, params=p.params())
    phis, states = np.array(phis), np.array(states)
    np.testing.assert_allclose(states, traj.states, rtol=1e-9, atol=1e-9 * np.abs(states[0]).max())
    np.testing.assert_allclose(phis, traj.phi, rtol=1e-9, atol=1e-9 * max(np.abs(phis).max(), 1.0))
    for s, ph in zip(states, phis, strict=True):  # the env's phi is NOTES.md's formula
        assert ph[0] == pytest.approx(usv_phi(s, current(s[0], s[1])), abs=1e-12)


# --------------------------------------------------------------------------- presets and starting states


PAPER_STATES = {
    # NOTES.md Section IV-A: positions (10,56), (30,100), (50,100), (10,90); velocities (0.5,1),
    # (1,1), (-1,-1), (0.6,0), laid out (x1..x4, z1..z4, xd1..xd4, zd1..zd4).
    "paper": [10, 30, 50, 10, 56, 100, 100, 90, 0.5, 1, -1, 0.6, 1, 1, -1, 0],
    # NOTES.md Section IV-B: q0 = (1, 1, pi/2); qd0 = (0.8, 0.5, 0) / (1, 1, 0).
    "paper-northeast": [1, 1, np.pi / 2, 0.8, 0.5, 0],
    "paper-anticyclone": [1, 1, np.pi / 2, 1, 1, 0],
}
PAPER_PARAMS = {"paper": {"masses": [2, 2, 2, 2], "g": 10}, "paper-northeast": {"m": 10, "I": 1.5},
                "paper-anticyclone": {"m": 20, "I": 4}}


@pytest.mark.parametrize("env_id, preset", [(e, p) for e in vnhc_gym.ENV_IDS for p in PRESETS[e]])
def test_preset_resets_to_the_paper_state(env_id, preset):
    expected = np.array(PAPER_STATES[preset], dtype=np.float64)
    env = make(env_id, preset=preset)
    for seed in (0, 1, 2, None, 12345):
        _, info = env.reset(seed=seed)
        np.testing.assert_array_equal(info["state"], expected)
        assert info["time"] == 0.0
        for a in action_seq(env_id, 5, seed=seed or 0):
            env.step(a)
    task = env.unwrapped.task
    names = task.model.param_names
    if env_id == FLOCK:
        np.testing.assert_array_equal(task.params_true[0], [*PAPER_PARAMS[preset]["masses"], 10.0])
    else:
        for key, value in PAPER_PARAMS[preset].items():
            assert task.params_true[0, names.index(key)] == value
    # The paper's phi(0) from NOTES.md's formula: flocking (0.6, 0.6, -0.6); north-east
    # 0.8 - 1 = -0.2; anticyclone 0 (already on the manifold).
    want = {"paper": [0.6, 0.6, -0.6], "paper-northeast": [-0.2], "paper-anticyclone": [0.0]}[preset]
    _, info = env.reset(seed=0)
    np.testing.assert_allclose(info["phi"], want, atol=1e-12)


def test_flocking_reset_is_off_the_manifold():
    env = raw(FLOCK)
    lo = 0.5 * math.sin(0.3)  # follower speed >= 0.5 |v_N|, angle to the leader in [0.3, 1.2] rad
    hi = 2.0 * math.sin(1.2)
    for seed in range(300):
        obs, info = env.reset(seed=seed)
        s = info["state"]
        x, z, xd, zd = s.reshape(4, 4)
        speed2 = xd[3] ** 2 + zd[3] ** 2
        ratio = np.abs(info["phi"]) / speed2
        assert np.all(ratio >= lo - 1e-12) and np.all(ratio <= hi + 1e-12), (seed, ratio)
        np.testing.assert_allclose(info["phi"], flock_phi(s), rtol=1e-12, atol=1e-12)
        assert 0.5 <= abs(xd[3]) <= 2.0 and 1.0 <= xd[3] - zd[3] <= 3.0
        assert (x[3], z[3]) == (0.0, 100.0)
        assert np.all(np.abs(x[:3]) <= 20.0) and np.all(np.abs(z[:3] - 100.0) <= 20.0)
        np.testing.assert_array_equal(info["force"], 0.0)


def test_usv_reset_is_off_the_manifold():
    env = raw(USV)
    for seed in range(200):
        obs, info = env.reset(seed=seed)
        s = info["state"]
        x, y, th, xd, yd, thd = s
        c = usv_current(env, x, y)
        phi = usv_phi(s, c)
        assert info["phi"][0] == pytest.approx(phi, abs=1e-12)
        assert 0.2 - 1e-12 <= abs(phi) <= 1.0 + 1e-12, (seed, phi)
        forward = (xd - c[0]) * math.cos(th) + (yd - c[1]) * math.sin(th)  # through the water
        ground = xd * math.cos(th) + yd * math.sin(th)  # over ground, along the heading
        assert forward >= 0.5 - 1e-12 and ground >= 0.3 - 1e-12
        assert forward <= 1.5 + 1e-12 or ground == pytest.approx(0.3, abs=1e-12)
        assert abs(x) <= 5 and abs(y) <= 5 and -math.pi <= th <= math.pi and abs(thd) <= 0.5


def test_flocking_observation_matches_docstring_table():
    env = raw(FLOCK)
    obs, info = env.reset(seed=4)
    for a in [None, *action_seq(FLOCK, 30)]:
        if a is not None:
            obs, _, _, _, info = env.step(a)
        s = info["state"]
        v = s[8:].reshape(2, 4).T  # (particle, (xd, zd))
        sp = np.hypot(*v[3])
        e = v[3] / sp
        r = v[:3] / sp
        want = np.concatenate([r.ravel(), e, [np.log(sp) / 5.0], e[0] * r[:, 1] - r[:, 0] * e[1]])
        np.testing.assert_allclose(obs, np.clip(want, -10, 10), rtol=2e-6, atol=2e-6)
        np.testing.assert_allclose(want[9:] * sp**2, info["phi"], rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("preset", ["paper-northeast", "paper-anticyclone"])
def test_usv_observation_matches_docstring_table(preset):
    env = raw(USV, preset=preset, domain=50.0)
    obs, info = env.reset(seed=0)
    for a in [None, *action_seq(USV, 30)]:
        if a is not None:
            obs, _, _, _, info = env.step(a)
        x, y, th, xd, yd, thd = info["state"]
        if preset == "paper-northeast":
            c, jac = (1.0, 1.0), [0, 0, 0, 0]
        else:
            c, jac = (y, -x + y), [0, 1, -1, 1]
        want = [math.cos(th), math.sin(th), xd / 2, yd / 2, thd / 2, c[0] / 2, c[1] / 2, x / 50, y / 50,
                usv_phi(info["state"], c) / 2, *jac]
        np.testing.assert_allclose(obs, np.clip(want, -10, 10), rtol=2e-6, atol=2e-6)


def test_reward_definition():
    for env_id in vnhc_gym.ENV_IDS:
        env = raw(env_id, phi_scale=2.0, action_cost=0.5, reward_clip=3.0)
        env.reset(seed=2)
        for a in action_seq(env_id, 60, lo=-1.0, hi=1.0):
            _, r, _, _, info = env.step(a)
            a64 = a.astype(np.float64)
            want = -np.mean(np.abs(info["phi"])) / 2.0 - 0.5 * np.mean(a64**2)
            assert r == pytest.approx(min(max(want, -3.0), 0.0), rel=1e-12, abs=1e-15)


# --------------------------------------------------------------------------- equations of motion


@pytest.mark.parametrize("scenario", ["nominal", "mismatch"])
def test_flocking_moves_by_its_equations_with_the_true_masses(scenario):
    """m_b xdd_b = u_b, m_b zdd_b = u_b - m_b g, leader free fall: constant accelerations, which
    RK4 integrates exactly, so one step changes the velocities by (u/m, u/m - g) dt."""
    env = raw(FLOCK, scenario=scenario)
    for seed in range(5):
        _, info = env.reset(seed=seed)
        m = env.unwrapped.task.params_true[0, :4]
        for a in action_seq(FLOCK, 10, seed=seed, lo=-1, hi=1):
            s0 = info["state"]
            _, _, _, _, info = env.step(a)
            u = a.astype(np.float64) * DEFAULT_BOUND[FLOCK]
            np.testing.assert_allclose(info["force"], u, rtol=1e-15)
            dv = info["state"][8:] - s0[8:]
            np.testing.assert_allclose(dv[:3], u / m[:3] * 0.05, rtol=1e-9, atol=1e-12)
            np.testing.assert_allclose(dv[4:7], (u / m[:3] - G) * 0.05, rtol=1e-9, atol=1e-12)
            assert dv[3] == 0.0 and dv[7] == pytest.approx(-G * 0.05, rel=1e-12)


@pytest.mark.parametrize("scenario", ["nominal", "mismatch"])
def test_usv_turns_by_its_equation_with_the_true_inertia(scenario):
    """I thetadd = u (no current term): thetad changes by u dt / I exactly."""
    env = raw(USV, scenario=scenario)
    names = env.unwrapped.task.model.param_names
    for seed in range(5):
        _, info = env.reset(seed=seed)
        inertia = env.unwrapped.task.params_true[0, names.index("I")]
        for a in action_seq(USV, 10, seed=seed, lo=-1, hi=1):
            thd0 = info["state"][5]
            _, _, term, _, info = env.step(a)
            expected = float(a[0]) * DEFAULT_BOUND[USV] * 0.05 / inertia
            assert info["state"][5] - thd0 == pytest.approx(expected, rel=1e-9, abs=1e-13)


# --------------------------------------------------------------------------- scenarios


@pytest.mark.parametrize("env_id", vnhc_gym.ENV_IDS)
def test_saturated_scenario_bound_and_clipping(env_id):
    """Docstring: saturated = force_bound_scale 0.05 (12.5 N flocking, 5 N USV); the geometric law
    with the baseline's default gain (k = 5) usually exceeds it at the start."""
    bound = 0.05 * DEFAULT_BOUND[env_id]
    env = raw(env_id, scenario="saturated")
    exceeded = 0
    for seed in range(100):
        _, info = env.reset(seed=seed)
        s = info["state"]
        if env_id == FLOCK:
            u = flock_law(s, np.full(4, 2.0), k=5.0)
        else:
            u = np.array([usv_law(s, usv_current(env, s[0], s[1]), 10.0, k=5.0)])
        exceeded += bool(np.any(np.abs(u) > bound))
        _, _, _, _, info = env.step(np.clip(u / bound, -1, 1))
        np.testing.assert_allclose(info["force"], np.clip(u, -bound, bound), rtol=1e-12)
    assert exceeded >= 80
    _, _, _, _, info = env.step(np.full(n_act(env_id), 7.0, np.float32))
    np.testing.assert_array_equal(info["force"], bound)


@pytest.mark.parametrize("env_id", vnhc_gym.ENV_IDS)
def test_mismatch_scenario_draws_true_parameters_per_episode(env_id):
    env = raw(env_id, scenario="mismatch")
    task = env.unwrapped.task
    names = task.model.param_names
    perturbed = [0, 1, 2] if env_id == FLOCK else [names.index("m"), names.index("I"), names.index("current_scale")]
    seen = []
    for seed in (0, 1, 2, 3, None, None):
        env.reset(seed=seed)
        true, nom = task.params_true[0].copy(), task.params_nominal[0].copy()
        ratio = true[perturbed] / nom[perturbed]
        assert np.all(ratio != 1.0) and np.all(np.abs(ratio - 1.0) <= 0.3)
        others = [i for i in range(len(names)) if i not in perturbed]
        np.testing.assert_array_equal(true[others], nom[others])
        seen.append(true[perturbed])
    assert len({tuple(v) for v in seen}) == len(seen)  # a new draw every episode
    env.reset(seed=0)
    np.testing.assert_array_equal(task.params_true[0][perturbed], seen[0])  # ... reproducible by seed
    nominal = raw(env_id)
    nominal.reset(seed=0)
    np.testing.assert_array_equal(nominal.unwrapped.task.params_true[0], nominal.unwrapped.task.params_nominal[0])


@pytest.mark.parametrize("env_id", vnhc_gym.ENV_IDS)
def test_info_has_documented_params(env_id):
    env = raw(env_id, scenario="mismatch")
    _, info = env.reset(seed=0)
    np.testing.assert_array_equal(info["params"], env.unwrapped.task.params_true[0])
    # Constant over an episode: in the reset's info only.
    info = env.step(env.action_space.sample())[4]
    assert "params" not in info and {"phi", "abs_phi", "state", "force", "time"} <= set(info)


@pytest.mark.parametrize("env_id", vnhc_gym.ENV_IDS)
def test_noisy_scenario_adds_documented_noise(env_id):
    noisy, clean = make(env_id, scenario="noisy"), make(env_id, scenario="noisy", obs_noise=0.0)
    o1, i1 = noisy.reset(seed=5)
    o2, i2 = clean.reset(seed=5)
    diffs = [o1.astype(np.float64) - o2]
    for a in action_seq(env_id, 300):
        o1, _, t1, _, i1 = noisy.step(a)
        o2, _, t2, _, i2 = clean.step(a)
        np.testing.assert_array_equal(i1["state"], i2["state"])  # noise only in what is observed
        assert t1 == t2
        inside = np.abs(o2) < 9.5  # away from the clip bounds
        diffs.append(np.where(inside, o1.astype(np.float64) - o2, np.nan))
    d = np.array(diffs)
    d = d[np.isfinite(d)]
    assert d.size > 1000
    assert np.std(d) == pytest.approx(0.02, rel=0.1)
    assert abs(np.mean(d)) < 0.02 * 5 / math.sqrt(d.size)
    assert np.mean(d == 0) < 0.01


@pytest.mark.parametrize("env_id", vnhc_gym.ENV_IDS)
def test_coarse_scenario_dt_and_substeps(env_id):
    # USV in the uniform current: its core RK4 is compiled anyway (the law test), the random field's would
    # cost a minute of numba compilation on a cold cache.
    env = raw(env_id, scenario="coarse", **({"current": "northeast"} if env_id == USV else {}))
    assert env.unwrapped.config.dt == 0.1 and env.unwrapped.config.substeps == 4
    _, info = env.reset(seed=0)
    a = action_seq(env_id, 1, lo=-1, hi=1)[0]
    s0 = info["state"]
    _, _, _, _, info = env.step(a)
    assert info["time"] == pytest.approx(0.1)
    model = make_flocking(4) if env_id == FLOCK else make_usv("northeast")
    params = env.unwrapped.task.params_true[0]
    u = a.astype(np.float64) * DEFAULT_BOUND[env_id]
    four = simulate(model, s0, 0.1, 1, feedback="open", u=u, params=params, substeps=4).states[-1]
    one = simulate(model, s0, 0.1, 1, feedback="open", u=u, params=params, substeps=1).states[-1]
    np.testing.assert_allclose(info["state"], four, rtol=1e-12, atol=1e-12)
    if env_id == USV:  # nonlinear: the substep count is visible
        assert not np.allclose(info["state"], one, rtol=1e-12, atol=1e-12)
    else:  # constant accelerations: leader falls g * 0.1 in one step
        assert info["state"][15] - s0[15] == pytest.approx(-G * 0.1, rel=1e-12)


@pytest.mark.parametrize("env_id", vnhc_gym.ENV_IDS)
def test_disturbance_scenario_kicks_velocities(env_id):
    """With impulses, some one-step velocity changes cannot come from the bounded force; without,
    all can.  Flocking: a follower's (dxd, dzd) must be (u/m, u/m - g) dt with |u| <= force_bound.
    USV (uniform current, zero action, so thetad is constant): |dv| <= force_bound dt / m + the
    current's share |W| dt / m <= 2 |C| |thetad| dt.  Kicks (the difference to an undisturbed twin
    stepped from the same state) hit follower / boat velocities only, in about impulse_prob = 5%
    of the steps, with std impulse_scale."""
    steps = 1500
    kw = {"current": "northeast"} if env_id == USV else {}
    bound, dt = DEFAULT_BOUND[env_id], 0.05
    results = {}
    for scenario in ("disturbance", "nominal"):
        env, twin = raw(env_id, scenario=scenario, **kw), raw(env_id, **kw)
        _, info = env.reset(seed=9)
        twin.reset(seed=9)
        actions = action_seq(env_id, steps, lo=-1, hi=1) if env_id == FLOCK else np.zeros((steps, 1), np.float32)
        unexplained, kicks = 0, []
        for a in actions:
            s0 = info["state"]
            twin.unwrapped.task.state[0] = s0  # the undisturbed step from the same state
            _, _, term, trunc, info = env.step(a)
            _, _, _, _, tinfo = twin.step(a)
            dv = info["state"] - s0
            if env_id == FLOCK:
                dx, dz = dv[8:11], dv[12:15]
                off_line = np.abs(dx - dz - G * dt) > 1e-9  # not on the segment (u/m, u/m - g) dt
                too_far = np.abs(dx) > bound * dt / 2.0 + 1e-9
                unexplained += int(np.any(off_line | too_far))
            else:
                limit = bound * dt / 10.0 + 2 * math.sqrt(2.0) * abs(s0[5]) * dt
                unexplained += int(math.hypot(dv[3], dv[4]) > limit)
            kick = info["state"] - tinfo["state"]
            if np.any(kick != 0):
                kicks.append(kick)
            if term or trunc:
                _, info = env.reset()
        results[scenario] = (unexplained, kicks)
    unexplained, kicks = results["disturbance"]
    # USV: ~75 kicks, each beyond the limit with probability ~exp(-0.5^2 / (2 * 0.3^2)) = 0.25,
    # so ~19 expected (sd ~4); 5 leaves a > 3 sd margin.  Nominal must explain every step.
    assert unexplained >= 5
    assert results["nominal"] == (0, [])
    kicks = np.array(kicks)
    assert 0.03 * steps <= len(kicks) <= 0.07 * steps
    if env_id == FLOCK:
        moved = np.zeros(16, bool)
        moved[[8, 9, 10, 12, 13, 14]] = True  # follower xd, zd
    else:
        moved = np.array([False, False, False, True, True, False])  # xd, yd
    assert np.all(kicks[:, ~moved] == 0)
    assert np.std(kicks[:, moved]) == pytest.approx(DEFAULT_KICK[env_id], rel=0.15)


# --------------------------------------------------------------------------- bad input


@pytest.mark.parametrize("env_id", vnhc_gym.ENV_IDS)
def test_non_finite_action_raises_and_changes_nothing(env_id):
    m = n_act(env_id)
    env, twin = make(env_id, scenario="noisy"), make(env_id, scenario="noisy")
    env.reset(seed=1)
    twin.reset(seed=1)
    good = action_seq(env_id, 6)
    bad = [np.full(m, np.nan, np.float32), np.full(m, np.inf), np.full(m, -np.inf), [np.nan] * m,
           np.array([0.1] * (m - 1) + [np.nan])]
    for a, b in zip(good, bad + bad[:1], strict=True):
        with pytest.raises(ValueError, match="finite"):
            env.step(b)
        same_step(env.step(a), twin.step(a))


@pytest.mark.parametrize("env_id", vnhc_gym.ENV_IDS)
def test_wrong_action_shape_raises(env_id):
    env = raw(env_id)
    env.reset(seed=0)
    m = n_act(env_id)
    for bad in (np.zeros(m + 1), np.zeros((1, m)), np.float64(0.2), [0.1] * (m + 2), np.zeros(0)):
        with pytest.raises(ValueError, match="shape"):
            env.step(bad)


@pytest.mark.parametrize("env_id", vnhc_gym.ENV_IDS)
def test_out_of_range_action_acts_like_the_bound(env_id):
    env, twin = make(env_id), make(env_id)
    env.reset(seed=2)
    twin.reset(seed=2)
    rng = np.random.default_rng(0)
    for _ in range(20):
        a = rng.choice([-1e30, -5.0, -1.0000001, 0.3, 1.5, 1e30], size=n_act(env_id))
        same_step(env.step(a), twin.step(np.clip(a, -1.0, 1.0)))


@pytest.mark.parametrize("env_id", vnhc_gym.ENV_IDS)
def test_huge_finite_action_acts_like_the_bound(env_id):
    env, twin = make(env_id), make(env_id)
    env.reset(seed=2)
    twin.reset(seed=2)
    a = np.full(n_act(env_id), -1e300)
    same_step(env.step(a), twin.step(np.clip(a, -1.0, 1.0)))


@pytest.mark.parametrize("env_id", vnhc_gym.ENV_IDS)
def test_other_action_dtypes_act_like_float64(env_id):
    env, twin = raw(env_id), raw(env_id)
    env.reset(seed=2)
    twin.reset(seed=2)
    a = np.full(n_act(env_id), 0.5)
    for other in (a.astype(np.float32), a.tolist(), tuple(a), np.ones(n_act(env_id), np.int64)):
        same_step(env.step(other), twin.step(np.asarray(other, dtype=np.float64)))


@pytest.mark.parametrize("dtype", [np.float16, ">f8"])
def test_float16_and_big_endian_actions(dtype):
    env, twin = raw(USV), raw(USV)
    env.reset(seed=2)
    twin.reset(seed=2)
    same_step(env.step(np.array([0.5], dtype=dtype)), twin.step(np.array([0.5])))


@pytest.mark.filterwarnings("ignore:.*render_mode='ansi':UserWarning")  # gym.make's own notice
@pytest.mark.parametrize("env_id, kwargs, valid_name", [
    (FLOCK, {"preset": "nope"}, "paper"),
    (USV, {"preset": "paper"}, "paper-northeast"),
    (FLOCK, {"scenario": "windy"}, "saturated"),
    (USV, {"scenario": "windy"}, "disturbance"),
    (USV, {"current": "gulfstream"}, "anticyclone"),
    (FLOCK, {"dtt": 0.1}, "dt"),
    (USV, {"n_agents": 4}, "domain"),
    (USV, {"render_mode": "ansi"}, "rgb_array"),
    (USV, {"current": "northeast", "current_params": {"c3": 1.0}}, "c1"),
])
def test_unknown_names_raise_listing_valid_ones(env_id, kwargs, valid_name):
    with pytest.raises(ValueError) as exc:
        make(env_id, **kwargs)
    assert valid_name in str(exc.value)


INVALID = [(FLOCK, "masses", v) for v in (0.0, -2.0, np.nan, [2.0, 2.0, 0.0, 2.0], [2.0, 2.0])]
INVALID += [(USV, "mass", v) for v in (0.0, -1.0, np.inf, np.nan)]
INVALID += [(USV, "inertia", v) for v in (0.0, -1.5)]
INVALID += [(e, "dt", v) for e in vnhc_gym.ENV_IDS for v in (0.0, -0.05, np.nan, np.inf)]
INVALID += [(e, "substeps", v) for e in vnhc_gym.ENV_IDS for v in (0, -1, 1.5, True)]
INVALID += [(e, "force_bound", v) for e in vnhc_gym.ENV_IDS for v in (0.0, -1.0, np.nan, np.inf)]
INVALID += [(FLOCK, "n_agents", v) for v in (1, 0, -3, 2.5, True)]
INVALID += [(FLOCK, "g", v) for v in (0.0, -10.0, np.nan)]
INVALID += [(USV, "domain", v) for v in (0.0, -5.0, np.nan)]
INVALID += [(e, "param_mismatch", v) for e in vnhc_gym.ENV_IDS for v in (1.0, 1.5, -0.1, np.nan)]
INVALID += [(e, "obs_noise", v) for e in vnhc_gym.ENV_IDS for v in (-0.01, np.nan, np.inf)]
INVALID += [(e, name, v) for e in vnhc_gym.ENV_IDS
            for name, v in (("impulse_prob", 1.5), ("impulse_prob", -0.1), ("impulse_scale", 0.0),
                            ("obs_clip", 0.0), ("reward_clip", -1.0), ("phi_scale", 0.0), ("action_cost", -1.0),
                            ("force_bound_scale", 0.0))]


@pytest.mark.parametrize("env_id, name, value", INVALID,
                         ids=[f"{SHORT[e]}-{n}={v!r}" for e, n, v in INVALID])
def test_invalid_numbers_raise_naming_the_argument(env_id, name, value):
    with pytest.raises(ValueError, match=rf"\b{name}\b"):
        make(env_id, **{name: value})


def test_force_bound_product_overflow_is_rejected():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with pytest.raises(ValueError, match="force_bound"):
            make(USV, force_bound=1e308, force_bound_scale=10.0)


# --------------------------------------------------------------------------- episode end


@pytest.mark.filterwarnings("error")
@pytest.mark.parametrize("env_id, kwargs", [
    (FLOCK, {"masses": 1e-308}),  # u / m overflows in the first RK4 stage
    (USV, {"inertia": 1e-308}),
    (USV, {"mass": 1e-308}),
])
def test_overflow_ends_episode_cleanly(env_id, kwargs):
    env = raw(env_id, **kwargs)
    obs0, info0 = env.reset(seed=0)
    with np.errstate(all="raise"):  # nothing on the Python side may overflow either
        obs, r, term, trunc, info = env.step(np.full(n_act(env_id), 0.5, np.float32))
    assert term and not trunc
    assert info["termination_reason"] == "non_finite_state"
    # Docstring: the last finite observation is returned with reward -reward_clip.
    np.testing.assert_array_equal(obs, obs0)
    assert env.observation_space.contains(obs)
    assert r == -100.0
    np.testing.assert_array_equal(info["phi"], info0["phi"])
    assert np.isfinite(info["abs_phi"])


@pytest.mark.filterwarnings("error")
def test_usv_state_overflow_in_rk4_ends_episode_cleanly():
    env = raw(USV)
    env.reset(seed=0)
    env.unwrapped.task.state[0, 3] = 1e308  # xd: x + dt xd stays finite, the current terms overflow
    env.unwrapped.task.state[0, 5] = 1e308
    with np.errstate(all="raise"):
        obs, r, term, trunc, info = env.step(np.array([0.5], np.float32))
    assert term and info["termination_reason"] == "non_finite_state"
    assert np.all(np.isfinite(obs)) and env.observation_space.contains(obs)
    assert math.isfinite(r) and r == -100.0
    assert np.all(np.isfinite(info["phi"]))


def test_usv_leaving_the_domain_terminates():
    env = make(USV, preset="paper-northeast", domain=1.2)
    env.reset(seed=0)  # starts at (1, 1), drifting north-east at ~1 m/s
    for k in range(1, 200):  # noqa: B007 (k used after the loop)
        obs, r, term, trunc, info = env.step(np.zeros(1, np.float32))
        x, y = info["state"][:2]
        assert term == (abs(x) > 1.2 or abs(y) > 1.2)
        if term:
            break
    assert term and info["termination_reason"] == "out_of_domain" and 1 < k < 200
    assert env.observation_space.contains(obs) and np.isfinite(r)


# --------------------------------------------------------------------------- rendering


@pytest.mark.parametrize("env_id, kwargs", [(FLOCK, {}), (FLOCK, {"preset": "paper"}), (USV, {}),
                                            (USV, {"preset": "paper-anticyclone"})])
def test_rgb_array_rendering(env_id, kwargs):
    env = make(env_id, render_mode="rgb_array", **kwargs)
    env.reset(seed=0)
    first = env.render()
    for a in action_seq(env_id, 200):  # 10 s: particles fall ~500 m, the camera must follow
        env.step(a)
    frame = env.render()
    for f in (first, frame):
        assert isinstance(f, np.ndarray) and f.dtype == np.uint8 and f.shape == (500, 500, 3)
        assert len(np.unique(f.reshape(-1, 3), axis=0)) > 5
    assert not np.array_equal(first, frame)
    red = (frame[..., 0] > 180) & (frame[..., 1] < 60) & (frame[..., 2] < 60)
    assert red.sum() > 20  # flocking: the leader in view; USV: the velocity arrow
    if env_id == USV:
        hull = np.all(frame == (90, 90, 90), axis=-1)
        rows, cols = np.nonzero(hull)
        assert hull.sum() > 100
        assert abs(rows.mean() - 250) < 40 and abs(cols.mean() - 250) < 40  # view centred on the boat
    env.close()
    env.close()  # closing twice is fine


@pytest.mark.parametrize("env_id", vnhc_gym.ENV_IDS)
def test_human_rendering_returns_none(env_id):
    env = make(env_id, render_mode="human")
    env.reset(seed=0)
    assert env.render() is None
    env.step(np.zeros(n_act(env_id), np.float32))
    env.close()


def test_renderers_survive_non_finite_and_huge_states():
    from vnhc_gym.envs.rendering import FlockingRenderer, USVRenderer

    fr = FlockingRenderer(4, "rgb_array", 20)
    ur = USVRenderer("rgb_array", 20)
    flock_states = [np.full(16, np.nan), np.full(16, 1e308), np.r_[np.full(8, 1e300), np.full(8, -1e300)],
                    np.r_[[np.inf, 0, 0, 0], np.zeros(12)], np.zeros(16)]
    for s in flock_states:
        f = fr.draw(s, np.array([np.nan, np.inf, 1.0]))
        assert f.shape == (500, 500, 3) and f.dtype == np.uint8
    for s in (np.full(6, np.nan), np.full(6, 1e300), np.array([1e13, -1e13, 1.0, 1e300, -1e300, 0.0])):
        f = ur.draw(s, np.array([np.nan]), lambda x, y: np.stack(np.broadcast_arrays(x * 0 + 1.0, y), axis=-1))
        assert f.shape == (500, 500, 3)
    f = ur.draw(np.zeros(6), np.zeros(1), lambda x, y: np.full((*np.shape(x), 2), np.nan))
    assert f.shape == (500, 500, 3)
    fr.close()
    ur.close()


def test_render_without_mode_warns():
    env = raw(FLOCK)
    env.reset(seed=0)
    with pytest.warns(UserWarning, match="render_mode"):
        assert env.render() is None


def test_usv_spinning_faster_than_the_turn_rate_limit_terminates():
    """Docstring: |thetad| > max_turn_rate ends the episode ("turn_rate_exceeded")."""
    env = raw(USV, max_turn_rate=2.0, force_bound=1000.0)
    env.reset(seed=0)
    for _ in range(50):
        _, r, term, _, info = env.step(np.ones(1, np.float32))  # I thetadd = u = 1000 N: spins up
        if term:
            break
    assert term and info["termination_reason"] == "turn_rate_exceeded"
    assert abs(info["state"][5]) > 2.0 and math.isfinite(r)
