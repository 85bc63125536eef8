"""A grid of training-and-evaluation runs, on one machine or a Ray cluster, resumable, and its report.

A run is one `RunSpec`: a learned agent (``ppo``, ``residual_ppo``, ``ppo_history``, ``sac``,
``residual_sac``) trained and tested (on Stable-Baselines3, or PPO and SAC on the compiled backend,
``backend="jax"``, reported as ``ppo-jax``, ``sac-jax``), a classical baseline (``law``, ``tuned_law``, ``safe_law``,
``observer``, ``kalman``, ``adaptive``, ``mpc``) tuned on validation episodes and tested, or the
headroom reference ``oracle`` (the sampled-data law on the true state and parameters), tuned and
tested the same way.  Every choice
(settings, checkpoints, the best classical baseline of a cell) and every table ranks on the
``score`` (the return over the fixed horizon per step, failed episodes' remaining steps counting
0), higher is better.

A run's outputs go to ``<out>/runs/<stem>.*`` under a stable name derived from its configuration,
with the sidecar (``<stem>.json``) written last: a run with a sidecar is finished.  Rerunning the
same grid skips finished runs, reruns failed or partial ones, and [`report`][vnhc_gym.sweep.report] warns when finished
runs come from different code versions.

Executors: ``local`` (an in-process loop, or ``jobs`` worker processes) and ``ray`` (one Ray task
per unit of work with its CPUs declared, retried ``retries`` times, then recorded as failed with
its traceback; a local Ray instance by default, a cluster with ``address``).  A unit of work is
one run, or the seeds of one compiled cell, which train in one program (`units`, `run_seeds`).
Both executors run the same units, so they give the same numbers for the same seeds.

The package re-exports its public names; each lives in one module:

- ``specs``: the grid (`RunSpec`, `grid`, `status`) and the algorithm names (``LEARNED_ALGOS``, ...);
- ``execute``: the executors (`run_one`, `run_seeds`, `run_sweep`, local or Ray), the units of
  work (`units`) and the GPUs a run asks Ray for (`gpus_of`);
- ``records``: the run records (`load_runs`, `save_records`, `restore_records`);
- ``cells``: the statistics of a cell (`Cell`, the rows of numbers a report writes);
- ``verdicts``: the written verdicts (`verdict`, ``headline.md``, the comparison tables);
- ``figures``: the report's figures;
- ``reporting``: `report`, which writes the cells' statistics as tables, verdicts and figures;
- ``cli``: ``vnhc-gym sweep`` (`add_arguments`, `run`).
"""

from __future__ import annotations

from vnhc_gym.sweep.cells import SCORE as SCORE
from vnhc_gym.sweep.cells import Cell as Cell
from vnhc_gym.sweep.cli import add_arguments as add_arguments
from vnhc_gym.sweep.cli import run as run
from vnhc_gym.sweep.execute import GPU_ALGOS as GPU_ALGOS
from vnhc_gym.sweep.execute import gpus_of as gpus_of
from vnhc_gym.sweep.execute import run_one, run_sweep
from vnhc_gym.sweep.execute import run_seeds as run_seeds
from vnhc_gym.sweep.execute import units as units
from vnhc_gym.sweep.records import load_runs, restore_records, save_records
from vnhc_gym.sweep.reporting import REPORT_REPS as REPORT_REPS
from vnhc_gym.sweep.reporting import report
from vnhc_gym.sweep.specs import ALL_ALGOS as ALL_ALGOS
from vnhc_gym.sweep.specs import (
    CLASSICAL_ALGOS,
    COMPILED_ALGOS,
    LEARNED_ALGOS,
    PLANNING_ALGOS,
    REFERENCE_ALGOS,
    RESIDUAL_ALGOS,
    RunSpec,
    grid,
    status,
)
from vnhc_gym.sweep.verdicts import NO_HEADROOM as NO_HEADROOM
from vnhc_gym.sweep.verdicts import verdict as verdict

__all__ = ["CLASSICAL_ALGOS", "COMPILED_ALGOS", "LEARNED_ALGOS", "PLANNING_ALGOS", "REFERENCE_ALGOS", "RESIDUAL_ALGOS",
           "RunSpec", "grid", "load_runs", "report", "restore_records", "run_one", "run_sweep",
           "save_records", "status"]
