#!/usr/bin/env python
"""Environment benchmark: single-env step time, vector throughput, JIT start-up.

    python experiments/bench_envs.py [--quick] [--out results] [--repeats 5]

One run measures, prints and writes ``<out>/bench_envs.json`` and ``<out>/bench_envs.md``:

1. **Single env** -- median time of one ``env.step`` of ``gym.make(id)`` (with Gymnasium's
   default wrappers, as users run it) for both environments and for ``Pendulum-v1`` in the
   same run; floor ``ratio <= 1.0`` (goal 0.5).
2. **Vector throughput** (env-steps/s) at ``N = 16, 256, 1024, 4096`` of the native vector env
   (``gym.make_vec(id, num_envs=N, vectorization_mode="vector_entry_point")``), of
   ``SyncVectorEnv`` over ``N`` single envs of the same id (fewer steps for big ``N``) and of
   Gymnasium's native ``CartPoleVectorEnv``.  The native env is timed over a full episode
   cycle from ``reset``: ``MAX_EPISODE_STEPS + 1`` = 401 steps, so every sub-env ends its
   episode once and is auto-reset once, inside the timing ("rollout"); "stepping" is ``N`` over
   the median step time (steps without resets).  Floors: at ``N = 4096`` native >= 1x
   ``CartPoleVectorEnv`` (goal 2x); at ``N = 1024`` native >= 100x ``SyncVectorEnv``.
3. **JIT start-up** -- wall time of ``python -c "import gymnasium as gym, vnhc_gym;
   gym.make(id).reset(seed=0)"`` in a fresh process with empty ``VNHC_GYM_CACHE_DIR`` and
   ``NUMBA_CACHE_DIR`` (cold: symbolic derivation, code generation and numba compilation) and
   again with the caches filled (cached), also with one ``step`` added (which compiles the
   step kernels); floor: cached adds < 1 s over ``python -c "import gymnasium"`` (the median of
   paired differences: each cached run right after an ``import gymnasium`` run).
4. **The USV's bound** -- at the largest ``N``, timed together with ``CartPoleVectorEnv``: the
   USV env with its default ``random`` current, with a constant current, and the random
   current's compiled physics alone: the open-loop RK4 step, and RK4 + ``phi`` + the current
   map (the least any step of that env costs).

Actions are drawn in advance with numpy (``action_space.sample()`` costs more than a step).
Every figure is the median over ``--repeats`` repeats, interleaved across the compared
environments so that a load change on the machine hits all of them alike; the load average
is recorded (other processes on a 2-core machine shift absolute numbers, and the threaded
kernel used for ``N >= 256`` suffers most from them).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from vnhc_gym.envs.task import N_CHUNKS

import vnhc_gym

ENV_IDS = vnhc_gym.ENV_IDS
PENDULUM = "Pendulum-v1"
CARTPOLE = "CartPole-v1"
SIZES = (16, 256, 1024, 4096)
QUICK_SIZES = (16, 256)

FLOOR_SINGLE = 1.0  # single-env step time / Pendulum-v1 (<=)
GOAL_SINGLE = 0.5
FLOOR_CARTPOLE = 1.0  # native / CartPoleVectorEnv at N = 4096 (>=)
GOAL_CARTPOLE = 2.0
FLOOR_SYNC = 100.0  # native / SyncVectorEnv at N = 1024 (>=)
FLOOR_JIT_S = 1.0  # cached start-up minus `import gymnasium` (<)


def short(env_id: str) -> str:
    return env_id.split("/")[-1]


def draw_actions(space: gym.Space, shape: tuple[int, ...], rng: np.random.Generator) -> np.ndarray:
    """Random actions of ``space`` (a Box or a Discrete / MultiDiscrete) for ``shape`` leading dims."""
    if isinstance(space, gym.spaces.Box):
        low = np.broadcast_to(space.low, space.shape)
        high = np.broadcast_to(space.high, space.shape)
        return rng.uniform(low, high, size=(*shape, *space.shape)).astype(space.dtype)
    if isinstance(space, gym.spaces.Discrete):
        return rng.integers(space.start, space.start + space.n, size=shape)
    if isinstance(space, gym.spaces.MultiDiscrete):
        return rng.integers(0, space.nvec, size=(*shape, *space.nvec.shape))
    raise TypeError(f"unsupported action space {space}")


# ---------------------------------------------------------------------------------------------- 1. single env
class SingleTimer:
    """Per-step timing of one ``gym.make`` env (resets between episodes are not timed)."""

    def __init__(self, env_id: str, steps: int) -> None:
        self.env = gym.make(env_id)
        self.env.reset(seed=0)
        self.actions = draw_actions(self.env.action_space, (steps,), np.random.default_rng(0))
        for a in self.actions[:50]:  # warm-up (JIT load, caches)
            if any(self.env.step(a)[2:4]):
                self.env.reset()

    def run(self) -> float:
        """Median seconds per step over one pass of the pre-drawn actions."""
        env = self.env
        times = np.empty(len(self.actions))
        perf = time.perf_counter
        for k, a in enumerate(self.actions):
            t0 = perf()
            _, _, terminated, truncated, _ = env.step(a)
            times[k] = perf() - t0
            if terminated or truncated:
                env.reset()
        return float(np.median(times))


def bench_single(steps: int, repeats: int) -> dict[str, Any]:
    timers = {env_id: SingleTimer(env_id, steps) for env_id in (PENDULUM, *ENV_IDS)}
    samples: dict[str, list[float]] = {k: [] for k in timers}
    for _ in range(repeats):
        for env_id, timer in timers.items():
            samples[env_id].append(timer.run())
    med = {k: statistics.median(v) for k, v in samples.items()}
    out: dict[str, Any] = {"pendulum_us": med[PENDULUM] * 1e6, "envs": {}}
    for env_id in ENV_IDS:
        ratio = med[env_id] / med[PENDULUM]
        out["envs"][env_id] = {"step_us": med[env_id] * 1e6, "ratio_vs_pendulum": ratio,
                               "pass": ratio <= FLOOR_SINGLE, "goal_met": ratio <= GOAL_SINGLE,
                               "samples_us": [s * 1e6 for s in samples[env_id]]}
    for timer in timers.values():
        timer.env.close()
    return out


# ---------------------------------------------------------------------------------------------- 2. vector
class VectorTimer:
    """Times ``steps`` consecutive steps of a vector env from ``reset(seed=...)``."""

    def __init__(self, env_id: str, n: int, steps: int, mode: str = "vector_entry_point", **kwargs: Any) -> None:
        self.env = gym.make_vec(env_id, num_envs=n, vectorization_mode=mode, **kwargs)
        self.n = n
        self.actions = draw_actions(self.env.single_action_space, (steps, n), np.random.default_rng(1))
        self.env.reset(seed=0)
        for a in self.actions[:3]:  # warm-up
            self.env.step(a)
        self.seed = 0
        if mode != "sync":
            # A whole untimed pass, so that the first auto-resets (and any kernel they load) happen here.
            self.run()

    def run(self) -> tuple[float, float]:
        """(rollout env-steps/s over all the steps, stepping env-steps/s from the median step)."""
        env = self.env
        self.seed += 1
        env.reset(seed=self.seed)
        times = np.empty(len(self.actions))
        perf = time.perf_counter
        for k, a in enumerate(self.actions):
            t0 = perf()
            env.step(a)
            times[k] = perf() - t0
        return self.n * len(times) / float(times.sum()), self.n / float(np.median(times))


def bench_vector(sizes: tuple[int, ...], repeats: int, cycle: int, sync_budget: int, log: Any) -> dict[str, Any]:
    rows: dict[str, Any] = {}
    for n in sizes:
        sync_steps = max(3, min(cycle, sync_budget // n))
        timers: dict[str, VectorTimer] = {}
        for env_id in ENV_IDS:
            timers[env_id] = VectorTimer(env_id, n, cycle)
            timers["sync:" + env_id] = VectorTimer(env_id, n, sync_steps, mode="sync")
        timers[CARTPOLE] = VectorTimer(CARTPOLE, n, cycle)
        samples: dict[str, list[tuple[float, float]]] = {k: [] for k in timers}
        for r in range(repeats):
            for key, timer in timers.items():
                if key.startswith("sync:") and r >= max(1, repeats // 2) and n >= 1024:
                    continue  # SyncVectorEnv at big N is slow and steady: fewer repeats
                samples[key].append(timer.run())
        for timer in timers.values():
            timer.env.close()
        med = {k: (statistics.median(s[0] for s in v), statistics.median(s[1] for s in v)) for k, v in samples.items()}
        cart = med[CARTPOLE][0]
        for env_id in ENV_IDS:
            roll, stepping = med[env_id]
            sync = med["sync:" + env_id][0]
            rows[f"{short(env_id)}/{n}"] = {
                "env": env_id, "n": n, "rollout_steps_per_s": roll, "stepping_steps_per_s": stepping,
                "sync_steps_per_s": sync, "sync_timed_steps": sync_steps, "cartpole_steps_per_s": cart,
                "ratio_cartpole": roll / cart, "ratio_cartpole_stepping": stepping / cart,
                "ratio_sync": roll / sync, "ratio_sync_stepping": stepping / sync}
            log(f"  N={n:5d} {short(env_id):18s} native {roll:10.3g}/s (stepping {stepping:10.3g}/s)  "
                f"sync {sync:9.3g}/s  CartPoleVectorEnv {cart:10.3g}/s")
    return rows


# ---------------------------------------------------------------------------------------------- 3. JIT
def _wall(code: str, env: dict[str, str]) -> float:
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-c", code], env=env, check=True, capture_output=True, text=True)
    return time.perf_counter() - t0


def bench_jit(repeats: int, cold: bool) -> dict[str, Any]:
    """Start-up walls; "over import" is the median of paired differences: each cached run is
    preceded by a run of ``import gymnasium``, so a load change on the machine (which shifts
    both by tenths of a second here) cancels out of the difference."""
    base_env = dict(os.environ)
    imports: list[float] = []
    out: dict[str, Any] = {"envs": {}}
    for env_id in ENV_IDS:
        row: dict[str, Any] = {}
        for label, code in (
                ("reset", f"import gymnasium as gym, vnhc_gym; gym.make({env_id!r}).reset(seed=0)"),
                ("reset_step", f"import gymnasium as gym, vnhc_gym; e = gym.make({env_id!r}); e.reset(seed=0); "
                               "e.step(e.action_space.sample())")):
            with tempfile.TemporaryDirectory(prefix="vnhc_bench_") as tmp:
                env = dict(base_env)
                if cold:
                    env["VNHC_GYM_CACHE_DIR"] = str(Path(tmp) / "codegen")
                    env["NUMBA_CACHE_DIR"] = str(Path(tmp) / "numba")
                    row[f"{label}_cold_s"] = _wall(code, env)
                else:  # quick: the default caches, assumed filled
                    row[f"{label}_cold_s"] = None
                walls, diffs = [], []
                for _ in range(repeats):
                    imp = _wall("import gymnasium", base_env)
                    wall = _wall(code, env)
                    imports.append(imp)
                    walls.append(wall)
                    diffs.append(wall - imp)
            row[f"{label}_cached_s"] = statistics.median(walls)
            row[f"{label}_over_import_s"] = statistics.median(diffs)
            row[f"{label}_over_import_samples_s"] = diffs
        row["pass"] = row["reset_over_import_s"] < FLOOR_JIT_S and row["reset_step_over_import_s"] < FLOOR_JIT_S
        out["envs"][env_id] = row
    out["import_gymnasium_s"] = statistics.median(imports)
    return out


# ---------------------------------------------------------------------------------------------- 4. USV bound
USV = "vnhc_gym/USVStream-v0"


class KernelTimer:
    """One of the USV's compiled physics kernels alone, on both cores, on the rows and episode
    parameters of a freshly reset vector env with the default ``random`` current.

    ``"rk4"``: the open-loop RK4 step (``kernels.rk4_parallel``) from a fixed state under random
    forces.  ``"advance"``: RK4, then ``phi`` (the reward's) and the current map at the new state
    (the observation's) -- ``kernels.advance_parallel``, the physics every step of the env must
    do, with no observation, reward or info; zero force, so the state drifts with the current.
    """

    def __init__(self, kind: str, n: int, steps: int) -> None:
        env = gym.make_vec(USV, num_envs=n, vectorization_mode="vector_entry_point")
        env.reset(seed=0)
        task: Any = env.unwrapped.task  # type: ignore[attr-defined]
        # The task's own argument tuple of advance (state, params, force, ..., NEXT, ..., aux); the
        # env is never stepped again, so the kernels may work on its buffers.  force is 0 after reset.
        aargs = task._advance_args[:17]
        if kind == "rk4":
            u = draw_actions(env.single_action_space, (n,), np.random.default_rng(1)).astype(np.float64)
            self.kernel, self.args = task.k.rk4_parallel, (*aargs[:2], task.force_bound * u, *aargs[3:13], N_CHUNKS)
        elif kind == "advance":
            self.kernel, self.args = task.k.advance_parallel, (*aargs, N_CHUNKS)
        else:
            raise ValueError(f"kind must be 'rk4' or 'advance', got {kind!r}")
        self.n, self.steps = n, steps
        self.env = env
        self.run()  # warm-up

    def run(self) -> tuple[float, float]:
        kernel, args = self.kernel, self.args
        t0 = time.perf_counter()
        for _ in range(self.steps):
            kernel(*args)
        rate = self.n * self.steps / (time.perf_counter() - t0)
        return rate, rate


def bench_usv_bound(n: int, repeats: int, cycle: int) -> dict[str, Any]:
    """The USV at ``n`` against CartPoleVectorEnv, timed together: the native env (default
    ``random`` current), the same env with the constant ``northeast`` current, and the random
    current's kernels alone (:class:`KernelTimer`).  If ``advance`` alone is below
    CartPoleVectorEnv's whole step, no USV step with that current can reach the CartPole floor
    on this machine."""
    timers: dict[str, Any] = {CARTPOLE: VectorTimer(CARTPOLE, n, cycle), "random": VectorTimer(USV, n, cycle),
                              "northeast": VectorTimer(USV, n, cycle, current="northeast"),
                              "rk4": KernelTimer("rk4", n, cycle), "advance": KernelTimer("advance", n, cycle)}
    samples: dict[str, list[float]] = {k: [] for k in timers}
    for _ in range(repeats):
        for key, timer in timers.items():
            samples[key].append(timer.run()[0])
    for timer in timers.values():
        timer.env.close()
    med = {k: statistics.median(v) for k, v in samples.items()}
    cart = med.pop(CARTPOLE)
    return {"n": n, "cartpole_steps_per_s": cart,
            "rows": {k: {"steps_per_s": v, "ratio_cartpole": v / cart} for k, v in med.items()}}


# ---------------------------------------------------------------------------------------------- report
def verdict(ok: bool) -> str:
    return "PASS" if ok else "FAIL"


def fmt_rate(x: float) -> str:
    return f"{x / 1e6:.2f} M" if x >= 1e6 else f"{x / 1e3:.1f} k"


def report(res: dict[str, Any]) -> str:
    meta = res["meta"]
    lines = [f"# Environment benchmark ({'quick' if meta['quick'] else 'full'} run)", "",
             f"{meta['platform']}, {meta['cpus']} CPUs, Python {meta['python']}, numpy {meta['numpy']}, "
             f"numba {meta['numba']} (threading layer {meta['threading_layer']}), gymnasium {meta['gymnasium']}; "
             f"load average {meta['load_before'][0]:.2f} before, {meta['load_after'][0]:.2f} after "
             f"(1-min); {meta['seconds']:.0f} s.", "",
             "## Single environment: median `env.step` of `gym.make(id)`", "",
             "| env | us/step | / Pendulum-v1 | floor <= 1.0 | goal <= 0.5 |",
             "|---|---:|---:|:---:|:---:|",
             f"| Pendulum-v1 | {res['single']['pendulum_us']:.2f} | 1.00 | | |"]
    for env_id, r in res["single"]["envs"].items():
        lines.append(f"| {short(env_id)} | {r['step_us']:.2f} | {r['ratio_vs_pendulum']:.2f} | "
                     f"{verdict(r['pass'])} | {'met' if r['goal_met'] else 'not met'} |")
    lines += ["", "## Vector throughput (env-steps/s)", "",
              "native = `make_vec(..., \"vector_entry_point\")` over a 401-step episode cycle (every sub-env "
              "resets once, included); stepping = N / median step time; Sync = `SyncVectorEnv` of `gym.make` "
              "envs (timed steps in brackets); CartPole = Gymnasium's `CartPoleVectorEnv` (401 steps).", "",
              "| env | N | native | stepping | Sync | CartPole | native / CartPole | native / Sync | floor |",
              "|---|---:|---:|---:|---:|---:|---:|---:|---|"]
    for r in res["vector"].values():
        floor = ""
        if r["n"] == 4096:
            floor = (f"CartPole >= 1x: {verdict(r['ratio_cartpole'] >= FLOOR_CARTPOLE)} "
                     f"(stepping {verdict(r['ratio_cartpole_stepping'] >= FLOOR_CARTPOLE)}; goal 2x "
                     f"{'met' if r['ratio_cartpole'] >= GOAL_CARTPOLE else 'not met'})")
        elif r["n"] == 1024:
            floor = (f"Sync >= 100x: {verdict(r['ratio_sync'] >= FLOOR_SYNC)} "
                     f"(stepping {verdict(r['ratio_sync_stepping'] >= FLOOR_SYNC)})")
        lines.append(f"| {short(r['env'])} | {r['n']} | {fmt_rate(r['rollout_steps_per_s'])} | "
                     f"{fmt_rate(r['stepping_steps_per_s'])} | {fmt_rate(r['sync_steps_per_s'])} "
                     f"({r['sync_timed_steps']}) | {fmt_rate(r['cartpole_steps_per_s'])} | "
                     f"{r['ratio_cartpole']:.2f} | {r['ratio_sync']:.1f} | {floor} |")
    b = res["usv_bound"]
    lines += ["", f"## USVStream-v0 at N = {b['n']} against CartPoleVectorEnv, timed together", "",
              "Kernels alone, on both cores, on a reset batch with the default `random` current: RK4 = the "
              "open-loop RK4 step (`kernels.rk4_parallel`); RK4 + phi + current map = `kernels.advance_parallel`, "
              "the physics that every step of the env does (the reward needs phi, the observation the current "
              "and its Jacobian at the new state), without observation, reward or info.", "",
              f"| what | env-steps/s | / CartPole ({fmt_rate(b['cartpole_steps_per_s'])}) |", "|---|---:|---:|"]
    names = {"random": "native env, `current=\"random\"` (default)",
             "northeast": "native env, `current=\"northeast\"` (constant)", "rk4": "RK4 alone, `random` current",
             "advance": "RK4 + phi + current map alone, `random` current"}
    for key, r in b["rows"].items():
        lines.append(f"| {names[key]} | {fmt_rate(r['steps_per_s'])} | {r['ratio_cartpole']:.2f} |")
    jit = res["jit"]
    lines += ["", "## JIT start-up: fresh `python -c \"import gymnasium as gym, vnhc_gym; "
              "gym.make(id).reset(seed=0)\"` (s)", "",
              f"`python -c \"import gymnasium\"`: {jit['import_gymnasium_s']:.2f} s. Cold: empty "
              "`VNHC_GYM_CACHE_DIR` and `NUMBA_CACHE_DIR`; cached: the same dirs, filled; \"- import\" is the "
              "median of paired differences (each cached run right after an `import gymnasium` run).", "",
              "| env | cold | cached | cached - import gymnasium | + step: cold | + step: cached | "
              "+ step: cached - import | floor < 1 s |", "|---|---:|---:|---:|---:|---:|---:|:---:|"]
    for env_id, r in jit["envs"].items():
        def s(x: float | None) -> str:
            return "skipped" if x is None else f"{x:.2f}"
        lines.append(f"| {short(env_id)} | {s(r['reset_cold_s'])} | {s(r['reset_cached_s'])} | "
                     f"{r['reset_over_import_s']:.2f} | {s(r['reset_step_cold_s'])} | {s(r['reset_step_cached_s'])} | "
                     f"{r['reset_step_over_import_s']:.2f} | {verdict(r['pass'])} |")
    lines += ["", "## Floors", ""]
    for f in res["floors"]:
        lines.append(f"- {verdict(f['pass'])}: {f['name']} = {f['value']:.3g} (floor {f['floor']}"
                     + (f", goal {f['goal']}" if f.get("goal") is not None else "") + ")")
    return "\n".join(lines) + "\n"


def floors(res: dict[str, Any]) -> list[dict[str, Any]]:
    out = []
    for env_id, r in res["single"]["envs"].items():
        out.append({"name": f"{short(env_id)} single step / Pendulum-v1", "value": r["ratio_vs_pendulum"],
                    "floor": f"<= {FLOOR_SINGLE}", "goal": f"<= {GOAL_SINGLE}", "pass": r["pass"]})
    for r in res["vector"].values():
        if r["n"] == 4096:
            for kind, key in (("rollout", "ratio_cartpole"), ("stepping", "ratio_cartpole_stepping")):
                out.append({"name": f"{short(r['env'])} N=4096 native ({kind}) / CartPoleVectorEnv", "value": r[key],
                            "floor": f">= {FLOOR_CARTPOLE}", "goal": f">= {GOAL_CARTPOLE}",
                            "pass": r[key] >= FLOOR_CARTPOLE})
        if r["n"] == 1024:
            for kind, key in (("rollout", "ratio_sync"), ("stepping", "ratio_sync_stepping")):
                out.append({"name": f"{short(r['env'])} N=1024 native ({kind}) / SyncVectorEnv", "value": r[key],
                            "floor": f">= {FLOOR_SYNC}", "pass": r[key] >= FLOOR_SYNC})
    for env_id, r in res["jit"]["envs"].items():
        for label in ("reset", "reset_step"):
            v = r[f"{label}_over_import_s"]
            out.append({"name": f"{short(env_id)} cached start-up ({label}) - import gymnasium [s]", "value": v,
                        "floor": f"< {FLOOR_JIT_S}", "pass": v < FLOOR_JIT_S})
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="small sizes, few steps, no cold JIT run (smoke test)")
    parser.add_argument("--out", type=Path, default=Path(__file__).resolve().parent.parent / "results",
                        help="folder for bench_envs.json and bench_envs.md (default: results/)")
    parser.add_argument("--repeats", type=int, default=None, help="repeats per measurement (default 5; quick 1)")
    args = parser.parse_args(argv)
    quick = args.quick
    repeats = args.repeats or (1 if quick else 5)
    t_start = time.perf_counter()
    load_before = os.getloadavg()

    def log(msg: str) -> None:
        print(msg, file=sys.stderr, flush=True)

    import numba

    log("single-env step times ...")
    single = bench_single(steps=300 if quick else 3000, repeats=repeats)
    log("vector throughput ...")
    cycle = 40 if quick else vnhc_gym.MAX_EPISODE_STEPS + 1
    vector = bench_vector(QUICK_SIZES if quick else SIZES, repeats=repeats, cycle=cycle,
                          sync_budget=2_000 if quick else 16_000, log=log)
    n_big = (QUICK_SIZES if quick else SIZES)[-1]
    log(f"USV bound at N = {n_big} ...")
    usv_bound = bench_usv_bound(n_big, repeats=repeats, cycle=cycle)
    log("JIT start-up ...")
    jit = bench_jit(repeats=1 if quick else 5, cold=not quick)
    res: dict[str, Any] = {
        "meta": {"quick": quick, "repeats": repeats, "platform": platform.platform(), "cpus": os.cpu_count(),
                 "python": platform.python_version(), "numpy": np.__version__, "numba": numba.__version__,
                 "threading_layer": _threading_layer(), "gymnasium": gym.__version__,
                 "load_before": list(load_before), "load_after": list(os.getloadavg()),
                 "seconds": time.perf_counter() - t_start, "command": " ".join([sys.executable, *sys.argv])},
        "single": single, "vector": vector, "usv_bound": usv_bound, "jit": jit}
    res["floors"] = floors(res)
    text = report(res)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "bench_envs.json").write_text(json.dumps(res, indent=2) + "\n")
    (args.out / "bench_envs.md").write_text(text)
    print(text)
    return 0


def _threading_layer() -> str:
    import numba

    try:
        return str(numba.threading_layer())
    except ValueError:  # no parallel kernel has run
        return "unused"


if __name__ == "__main__":
    sys.exit(main())
