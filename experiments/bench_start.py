"""Start-up of a new process, for every registered environment and for ``vnhc-gym benchmark --quick``.
Writes results/bench_start.md and .json.

    python experiments/bench_start.py      # about 3 minutes

Nothing compiled survives a process (no kernel cache): every new process imports the package,
compiles its JAX programs and runs.  "first" is the first process after the script starts (cold OS
file caches for a fresh install are not reproduced), "again" the median of ``--repeats`` more, and
"over import" subtracts a plain ``import gymnasium`` (the median of paired runs).
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
    env = dict(os.environ)
    for env_id, extra in cases:
        cmd = [sys.executable, "-c", ENV_SNIPPET.format(env=env_id, extra=extra)]
        first, output = timed(cmd, env)
        diffs, again = [], []
        for _ in range(args.repeats):
            base, _ = timed([sys.executable, "-c", "import gymnasium"], env)
            seconds, _ = timed(cmd, env)
            again.append(seconds)
            diffs.append(seconds - base)
        rows.append({"what": env_id + extra.replace(", ", " "), "first": first, "again": statistics.median(again),
                     "over_import": statistics.median(diffs), "peak_rss_mb": peak_mb(output)})
        print(rows[-1], flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        cmd = ["vnhc-gym", "benchmark", "--quick", "--out", f"{tmp}/bench"]
        first, _ = timed(cmd, {**env, "MPLBACKEND": "Agg"})
        again, _ = timed(cmd, {**env, "MPLBACKEND": "Agg"})
    rows.append({"what": "vnhc-gym benchmark --quick", "first": first, "again": again, "over_import": None,
                 "peak_rss_mb": None})
    print(rows[-1], flush=True)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "bench_start.json").write_text(json.dumps(rows, indent=1))
    lines = ["| what | first (s) | again (s) | again over `import gymnasium` (s) | peak memory (MB) |",
             "|---|---:|---:|---:|---:|"]
    for r in rows:
        over = "" if r["over_import"] is None else f"{r['over_import']:.2f}"
        mem = "" if r["peak_rss_mb"] is None else str(r["peak_rss_mb"])
        lines.append(f"| {r['what']} | {r['first']:.1f} | {r['again']:.2f} | {over} | {mem} |")
    (out / "bench_start.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
