"""Start-up of a new process, for every registered environment and for ``vnhc-gym benchmark --quick``.
Writes results/bench_start.md and .json.

    python experiments/bench_start.py      # about 3 minutes

A Python process keeps nothing compiled (the package writes no cache): every new process imports the
package, compiles its JAX programs and runs.  "first" is the first process after the script starts
(cold OS file caches for a fresh install are not reproduced), "again" the median of ``--repeats``
more, and "over import" subtracts a plain ``import gymnasium`` (the median of paired runs).  The
"with JAX's compilation cache" is a new process that finds the compiled programs of an earlier one
(``JAX_COMPILATION_CACHE_DIR``, which the ``vnhc-gym`` command sets for itself): the median of
``--repeats``.  The command's "first" run starts from an empty cache folder, its second finds the
first run's programs there.
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


def timed(cmd: list[str], env: dict[str, str]) -> tuple[float, str]:
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True, check=True)
    return time.perf_counter() - t0, proc.stderr + proc.stdout


def peak_mb(output: str) -> int | None:
    for line in output.splitlines():
        if line.startswith("peak_rss_mb"):
            return int(line.split()[1])
    return None


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", default="results/bench_start")
    args = ap.parse_args()
    rows = []
    cases = [(env_id, "") for env_id in env_ids("v1")]
    # The flock's compile time and memory do not grow with its size (jax.vmap over one printed unit).
    cases += [("vnhc_gym/FlockingAlign-v1", f", n_agents={n}") for n in (100, 1000)]
    # No compilation cache of the caller's: each process compiles what it runs.
    env = {k: v for k, v in os.environ.items() if k not in ("JAX_COMPILATION_CACHE_DIR", "VNHC_GYM_JAX_CACHE")}
    for env_id, extra in cases:
        cmd = [sys.executable, "-c", ENV_SNIPPET.format(env=env_id, extra=extra)]
        first, output = timed(cmd, env)
        diffs, again = [], []
        for _ in range(args.repeats):
            base, _ = timed([sys.executable, "-c", "import gymnasium"], env)
            seconds, _ = timed(cmd, env)
            again.append(seconds)
            diffs.append(seconds - base)
        with tempfile.TemporaryDirectory() as tmp:  # a process that finds the last one's compiled programs
            cached_env = {**env, "JAX_COMPILATION_CACHE_DIR": tmp, "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS": "0"}
            timed(cmd, cached_env)
            cached = statistics.median(timed(cmd, cached_env)[0] for _ in range(args.repeats))
        rows.append({"what": env_id + extra.replace(", ", " "), "first": first, "again": statistics.median(again),
                     "over_import": statistics.median(diffs), "cached": cached, "peak_rss_mb": peak_mb(output)})
        print(rows[-1], flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        # The command keeps its compiled programs in a cache folder: empty for the first run, the
        # first run's for the second.
        cmd = ["vnhc-gym", "benchmark", "--quick", "--out", f"{tmp}/bench"]
        cli_env = {**env, "MPLBACKEND": "Agg", "VNHC_GYM_JAX_CACHE": f"{tmp}/jax"}
        first, _ = timed(cmd, cli_env)
        again, _ = timed(cmd, cli_env)
    rows.append({"what": "vnhc-gym benchmark --quick", "first": first, "again": None, "over_import": None,
                 "cached": again, "peak_rss_mb": None})
    print(rows[-1], flush=True)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "bench_start.json").write_text(json.dumps(rows, indent=1))
    lines = ["| what | first (s) | again (s) | again over `import gymnasium` (s) | with JAX's compilation cache (s) "
             "| peak memory (MB) |", "|---|---:|---:|---:|---:|---:|"]
    for r in rows:
        again = "" if r["again"] is None else f"{r['again']:.2f}"
        over = "" if r["over_import"] is None else f"{r['over_import']:.2f}"
        mem = "" if r["peak_rss_mb"] is None else str(r["peak_rss_mb"])
        lines.append(f"| {r['what']} | {r['first']:.1f} | {again} | {over} | {r['cached']:.2f} | {mem} |")
    (out / "bench_start.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
