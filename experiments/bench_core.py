#!/usr/bin/env python
"""Micro-benchmark of the geometric core: the law and one RK4 step, batch 1 and 4096.

    python experiments/bench_core.py [--repeats 7] [--big 4096]

For the flocking system (4 agents) and the USV (north-east and random currents) it times

* ``law``      -- ``model.kernels.law`` called directly with preallocated arrays,
* ``control``  -- the checked public API ``model.control`` (argument checks + allocation),
* ``rk4 open / continuous / sampled`` -- ``model.kernels.rk4`` with modes 0, 1, 2,
* ``rk4_parallel`` -- ``model.kernels.rk4_parallel(..., n_chunks=2)`` (big batch only),

in microseconds per call and million system-steps (rows x calls) per second, after a warm-up,
as the median of several repeats.  Floors (PASS/FAIL): one flocking RK4 step at batch 1 takes
<= 20 us (every mode), and the flocking RK4 throughput at batch 4096 is >= 5 million
system-steps/s (every mode, the faster of ``rk4`` and ``rk4_parallel``).  Timings are wall
clock: run it on an otherwise idle machine.  Finally it reports the cold and warm start of ``make_flocking`` in a
fresh interpreter (the generated module and numba's machine code are cached on disk, so the
second start should only load them).
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time
from collections.abc import Callable
from functools import partial

import numba
import numpy as np

from vnhc_gym.mechanics import FEEDBACK_MODES, ConstrainedSystem
from vnhc_gym.systems import make_flocking, make_usv

FLOOR_STEP_US = 20.0  # one flocking RK4 step at batch 1
FLOOR_MSTEPS = 5.0  # million system-steps/s at the big batch (flocking)
DT = 0.01


def _time_per_call(fn: Callable[[], object], repeats: int, target_s: float = 0.05) -> tuple[float, float]:
    """Median (wall, CPU) seconds per call of ``fn`` over ``repeats`` timed loops of about ``target_s`` each.

    CPU time is the whole process's (all threads); on a busy machine it shows how much of the
    wall time was spent waiting for a core.
    """
    for _ in range(3):  # warm-up (compilation, caches)
        fn()
    t0 = time.perf_counter()
    fn()
    one = max(time.perf_counter() - t0, 1e-7)
    n = max(1, min(100_000, int(target_s / one)))
    wall, cpu = [], []
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        for _ in range(n):
            fn()
        wall.append((time.perf_counter() - t0) / n)
        cpu.append((time.process_time() - c0) / n)
    return statistics.median(wall), statistics.median(cpu)


def _states(model: ConstrainedSystem, batch: int, rng: np.random.Generator) -> np.ndarray:
    s = rng.uniform(-2.0, 2.0, (batch, 2 * model.n))
    if model.name.startswith("flocking"):
        na = model.n // 2
        s[:, 4 * na - 1] = s[:, 3 * na - 1] - rng.uniform(0.5, 3.0, batch)  # keep C regular
    return np.ascontiguousarray(s)


def bench_system(label: str, model: ConstrainedSystem, batches: tuple[int, ...], repeats: int,
                 rows: list[tuple[str, str, int, float, float, str]]) -> None:
    rng = np.random.default_rng(0)
    k = model.kernels
    m = model.m
    lo, hi = np.full(m, -np.inf), np.full(m, np.inf)
    tol = model.singular_tol
    for b in batches:
        s = _states(model, b, rng)
        p = np.ascontiguousarray(np.broadcast_to(model.default_params, (b, model.default_params.size)))
        gains = np.ones((b, model.n_gains))
        u_hold = np.zeros((b, m))
        u_out = np.empty((b, m))
        out = np.empty_like(s)
        flags = np.empty(b, dtype=np.int64)
        u_law = np.empty((b, m))

        t, c = _time_per_call(partial(k.law, s, p, gains, tol, u_law, flags), repeats)
        rows.append((label, "law (kernel)", b, t, c, ""))
        t, c = _time_per_call(partial(model.control, s, gains=gains, params=p), repeats)
        rows.append((label, "control (checked API)", b, t, c, ""))
        for mode_name in ("open", "continuous", "sampled"):
            mode = FEEDBACK_MODES[mode_name]
            t, c = _time_per_call(partial(k.rk4, s, p, u_hold, gains, mode, lo, hi, DT, 1, tol, out, u_out, flags),
                                  repeats)
            rows.append((label, f"rk4 {mode_name}", b, t, c, _floor(label, b, t, batches)))
        if b >= 1024:
            for mode_name in ("open", "continuous", "sampled"):
                mode = FEEDBACK_MODES[mode_name]
                t, c = _time_per_call(partial(k.rk4_parallel, s, p, u_hold, gains, mode, lo, hi, DT, 1, tol, out,
                                              u_out, flags, 2), repeats)
                rows.append((label, f"rk4_parallel {mode_name} (2 chunks)", b, t, c, _floor(label, b, t, batches)))


def _floor(label: str, b: int, t: float, batches: tuple[int, ...]) -> str:
    if not label.startswith("flocking"):
        return ""
    if b == 1:
        return f"<= {FLOOR_STEP_US:g} us: " + ("PASS" if t * 1e6 <= FLOOR_STEP_US else "FAIL")
    if b == max(batches):
        return f">= {FLOOR_MSTEPS:g} M/s: " + ("PASS" if b / t / 1e6 >= FLOOR_MSTEPS else "FAIL")
    return ""


def startup_times() -> list[float]:
    """Wall time of import + make_flocking(4) + one control call, in two fresh interpreters."""
    code = ("import time; t = time.time(); import numpy as np; from vnhc_gym.systems import make_flocking; "
            "m = make_flocking(4); s = np.zeros(16); s[15] = -1.0; m.control(s); print(time.time() - t)")
    times = []
    for _ in range(2):
        proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
        times.append(float(proc.stdout.strip().splitlines()[-1]))
    return times


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=7, help="timed repeats per row (median reported)")
    parser.add_argument("--big", type=int, default=4096, help="the big batch size")
    parser.add_argument("--no-startup", action="store_true", help="skip the cold/warm start measurement")
    args = parser.parse_args(argv)

    systems = [("flocking (4 agents)", make_flocking(4)), ("usv northeast", make_usv("northeast")),
               ("usv random", make_usv("random"))]
    rows: list[tuple[str, str, int, float, float, str]] = []
    for label, model in systems:
        bench_system(label, model, (1, args.big), args.repeats, rows)

    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"numba {numba.__version__}, threading layer {numba.threading_layer()}, {os.cpu_count()} CPUs, "
          f"load average {load:.2f}; wall-clock medians of {args.repeats} repeats")
    header = (f"{'system':<20} {'operation':<34} {'batch':>6} {'us/call':>10} {'M steps/s':>10} "
              f"{'cpu us/call':>11}  floor (wall)")
    print(header)
    print("-" * len(header))
    for label, op, b, t, c, floor in rows:
        print(f"{label:<20} {op:<34} {b:>6} {t * 1e6:>10.2f} {b / t / 1e6:>10.3f} {c * 1e6:>11.2f}  {floor}")
    print()
    # Floors: every flocking RK4 mode at batch 1; at the big batch the faster of rk4 / rk4_parallel per mode.
    flock = [r for r in rows if r[0].startswith("flocking") and r[1].startswith("rk4")]
    worst_us = max(t for _, _, b, t, _, _ in flock if b == 1) * 1e6
    best = {mode: max(b / t / 1e6 for _, op, b, t, _, _ in flock if b == args.big and op.split()[1] == mode)
            for mode in ("open", "continuous", "sampled")}
    ok_step = worst_us <= FLOOR_STEP_US
    ok_rate = min(best.values()) >= FLOOR_MSTEPS
    print(f"floor: flocking RK4 step at batch 1, slowest mode {worst_us:.2f} us <= {FLOOR_STEP_US:g} us: "
          f"{'PASS' if ok_step else 'FAIL'}")
    print(f"floor: flocking RK4 at batch {args.big}, best of rk4/rk4_parallel per mode "
          + ", ".join(f"{m} {v:.2f}" for m, v in best.items())
          + f" M steps/s >= {FLOOR_MSTEPS:g}: {'PASS' if ok_rate else 'FAIL'}")
    failed = not (ok_step and ok_rate)
    slow_par = [(r[0], r[1]) for r in rows if r[1].startswith("rk4_parallel")
                and r[3] > 1.5 * next(q[3] for q in rows if q[0] == r[0] and q[2] == r[2]
                                      and q[1] == "rk4 " + r[1].split()[1])]
    if slow_par:
        print(f"note: rk4_parallel is slower than rk4 in {len(slow_par)} rows; on a busy machine the '"
              f"{numba.threading_layer()}' threading layer's spin-waiting makes every parallel call wait for a "
              "descheduled worker (try OMP_WAIT_POLICY=passive or NUMBA_THREADING_LAYER=workqueue)")
    if not args.no_startup:
        cold, warm = startup_times()
        print(f"make_flocking(4) start in a fresh interpreter (import + build + first control call): "
              f"first {cold:.2f} s, second {warm:.2f} s")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
