"""Start-up of a new process: cold (empty kernel caches) and warm, for every registered environment,
and the cold ``vnhc-gym benchmark --quick``.  Writes results/bench_start.md and .json.

    python experiments/bench_start.py      # about 3 minutes

Cold means a first use on a new machine: ``VNHC_GYM_CACHE_DIR`` and ``NUMBA_CACHE_DIR`` point to
empty folders, so every kernel is generated and compiled.  Warm repeats the command with the
filled folders; "over import" subtracts a plain ``import gymnasium`` (the median of paired runs).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from vnhc_gym.tasks import env_ids

ENV_SNIPPET = ("import gymnasium as gym, vnhc_gym; env = gym.make({env!r}{extra}); env.reset(seed=0); "
               "env.step(env.action_space.sample()); import resource; "
               "print('peak_rss_mb', resource.getrusage(resource.RUSAGE_SELF).ru_maxrss // 1024)")


def timed(code: str, env: dict[str, str]) -> tuple[float, str]:
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    return time.perf_counter() - t0, proc.stderr + proc.stdout


def peak_mb(output: str) -> int | None:
    for line in output.splitlines():
        if line.startswith("peak_rss_mb"):
            return int(line.split()[1])
    return None


def timed_cmd(cmd: list[str], env: dict[str, str]) -> tuple[float, str]:
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True, check=True)
    return time.perf_counter() - t0, proc.stderr


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", default="results/bench_start")
    args = ap.parse_args()
    rows = []
    cases = [(env_id, "") for env_id in env_ids("v1")]
    # The flock's compile time and memory do not grow with its size (a fleet of one compiled unit).
    cases += [("vnhc_gym/FlockingAlign-v1", f", n_agents={n}") for n in (100, 1000)]
    for env_id, extra in cases:
        with tempfile.TemporaryDirectory() as tmp:
            env = {**os.environ, "VNHC_GYM_CACHE_DIR": f"{tmp}/vnhc", "NUMBA_CACHE_DIR": f"{tmp}/numba"}
            cold, output = timed(ENV_SNIPPET.format(env=env_id, extra=extra), env)
            diffs, warms = [], []
            for _ in range(args.repeats):
                base, _ = timed("import gymnasium", env)
                warm, _ = timed(ENV_SNIPPET.format(env=env_id, extra=extra), env)
                warms.append(warm)
                diffs.append(warm - base)
        rows.append({"what": env_id + extra.replace(", ", " "), "cold": cold, "warm": statistics.median(warms),
                     "warm_over_import": statistics.median(diffs), "notice": "compiling kernels" in output,
                     "peak_rss_mb": peak_mb(output)})
        print(rows[-1], flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        env = {**os.environ, "VNHC_GYM_CACHE_DIR": f"{tmp}/vnhc", "NUMBA_CACHE_DIR": f"{tmp}/numba",
               "MPLBACKEND": "Agg"}
        cold, notice = timed_cmd(["vnhc-gym", "benchmark", "--quick", "--out", f"{tmp}/bench"], env)
        warm, _ = timed_cmd(["vnhc-gym", "benchmark", "--quick", "--out", f"{tmp}/bench"], env)
    rows.append({"what": "vnhc-gym benchmark --quick", "cold": cold, "warm": warm, "warm_over_import": None,
                 "notice": "compiling kernels" in notice, "peak_rss_mb": None})
    print(rows[-1], flush=True)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "bench_start.json").write_text(json.dumps(rows, indent=1))
    lines = ["| what | cold (s) | warm (s) | warm over `import gymnasium` (s) | peak memory, cold (MB) "
             "| notice printed when cold |", "|---|---:|---:|---:|---:|---|"]
    for r in rows:
        over = "" if r["warm_over_import"] is None else f"{r['warm_over_import']:.2f}"
        mem = "" if r["peak_rss_mb"] is None else str(r["peak_rss_mb"])
        lines.append(f"| {r['what']} | {r['cold']:.1f} | {r['warm']:.2f} | {over} | {mem} | "
                     f"{'yes' if r['notice'] else 'no'} |")
    (out / "bench_start.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
