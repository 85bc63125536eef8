"""The grid of a sweep: `RunSpec` (one run), `grid` (every combination), `status` (done, failed or to
do), and the algorithms a run may name."""

from __future__ import annotations

import hashlib
import json
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from vnhc_gym.wrappers.residual_jax import BASES as COMPILED_BASES

#: Learned agents (trained with vnhc_gym.training), classical baselines (vnhc_gym.baselines.tuning)
#: and the headroom reference (not a controller one could field: never a cell's best classical).
LEARNED_ALGOS = ("ppo", "residual_ppo", "ppo_history", "sac", "residual_sac")
#: Learned agents that correct a classical base (the cell's best classical baseline).
RESIDUAL_ALGOS = ("residual_ppo", "residual_sac")
CLASSICAL_ALGOS = ("law", "tuned_law", "safe_law", "observer", "kalman", "adaptive", "mpc", "actuated_law",
                   "actuated_nominal", "actuated_dob")
#: Classical baselines that plan (model-predictive control): fielded as they are, never a residual base.
PLANNING_ALGOS = ("mpc",)
REFERENCE_ALGOS = ("oracle", "informed_kalman", "informed_actuated")
ALL_ALGOS = LEARNED_ALGOS + CLASSICAL_ALGOS + REFERENCE_ALGOS
#: Where a learned run trains: Stable-Baselines3 (and SBX), or compiled with its environment
#: (`vnhc_gym.training.run_jax`: PPO, SAC, their residual variants, PPO with history).  Classical runs
#: have no backend.
SWEEP_BACKENDS = ("sb3", "jax")
#: The learned agents the compiled backend trains; its residual agents' bases are the classical
#: baselines written in JAX (`COMPILED_BASES`: the law, and the law on the Kalman filter).
COMPILED_ALGOS = ("ppo", "residual_ppo", "ppo_history", "sac", "residual_sac")


def label(algo: str, backend: str = "sb3") -> str:
    """A run's name in the report: its algorithm, with ``-jax`` for the compiled backend (so that
    both backends' runs of one algorithm are compared, never pooled)."""
    return algo if backend == "sb3" else f"{algo}-{backend}"


def algo_of(name: str) -> str:
    """The algorithm of a report's entry (`label`'s inverse): ``"ppo-jax"`` -> ``"ppo"``."""
    return name.rsplit("-", 1)[0] if name.rsplit("-", 1)[-1] in SWEEP_BACKENDS else name


@dataclass(frozen=True)
class RunSpec:
    """One run of a sweep: what to train or tune, where, with which seed and budget."""

    algo: str
    env: str
    scenario: str = "nominal"
    seed: int = 0
    n_timesteps: int = 1_000_000
    overrides: tuple[tuple[str, Any], ...] = ()  #: hyperparameter overrides, as sorted pairs
    test_episodes: int = 20
    eval_episodes: int = 10
    #: A residual agent's candidate bases (its cell's best of them is its base); empty: every
    #: classical baseline but the planner.
    bases: tuple[str, ...] = ()
    #: A learned run's training backend (`SWEEP_BACKENDS`); the compiled one trains `COMPILED_ALGOS`,
    #: and a cell's seeds of it train in one program.
    backend: str = "sb3"

    def __post_init__(self) -> None:
        if self.algo not in ALL_ALGOS:
            raise ValueError(f"algo must be one of {list(ALL_ALGOS)}, got {self.algo!r}")
        if self.backend not in SWEEP_BACKENDS:
            raise ValueError(f"backend must be one of {list(SWEEP_BACKENDS)}, got {self.backend!r}")
        if self.backend == "jax" and self.algo not in COMPILED_ALGOS:
            raise ValueError(f"backend 'jax' trains {list(COMPILED_ALGOS)} only, got {self.algo!r}")
        object.__setattr__(self, "bases", tuple(self.bases))
        bad = [b for b in self.bases if b not in CLASSICAL_ALGOS or b in PLANNING_ALGOS]
        if bad:
            raise ValueError(f"bases must be classical baselines other than the planner, got {bad}")
        if self.backend == "jax" and self.algo in RESIDUAL_ALGOS and not (
                self.bases and set(self.bases) <= set(COMPILED_BASES)):
            raise ValueError(f"a residual run of backend 'jax' needs bases among {list(COMPILED_BASES)}, got "
                             f"{list(self.bases)}")

    @property
    def learned(self) -> bool:
        return self.algo in LEARNED_ALGOS

    def key(self) -> str:
        """A hash of the configuration (classical runs ignore the budget)."""
        d = asdict(self)
        for name in ("bases", "backend"):  # at their defaults: the keys of earlier grids stay as they were
            if d[name] == RunSpec.__dataclass_fields__[name].default:
                d.pop(name)
        if not self.learned:
            d.pop("n_timesteps")
            d.pop("seed")
        return hashlib.sha256(json.dumps(d, sort_keys=True, default=str).encode()).hexdigest()[:10]

    @property
    def label(self) -> str:
        """The run's name in the report (`label`)."""
        return label(self.algo, self.backend)

    @property
    def stem(self) -> str:
        seed = f"-s{self.seed}" if self.learned else ""
        return f"{self.env}-{self.scenario}-{self.label}{seed}-{self.key()}"


def grid(envs: Sequence[str], scenarios: Sequence[str], algos: Sequence[str], seeds: Sequence[int],
         n_timesteps: int, *, overrides: dict[str, Any] | None = None, test_episodes: int = 20,
         eval_episodes: int = 10, seeds_by_scenario: dict[str, Sequence[int]] | None = None,
         backend: str = "sb3") -> list[RunSpec]:
    """Every combination; classical baselines get one run per cell (they are deterministic).  A
    residual agent's base is the best of the grid's own classical baselines of its cell (all of them
    but the planner when the grid has none; on the compiled backend, those of `COMPILED_BASES`).
    ``backend`` is where the `COMPILED_ALGOS` train; every other learned run trains on ``"sb3"``."""
    ov = tuple(sorted((overrides or {}).items()))
    bases = tuple(a for a in algos if a in CLASSICAL_ALGOS and a not in PLANNING_ALGOS)
    compiled_bases = tuple(a for a in bases if a in COMPILED_BASES) or COMPILED_BASES
    out = []
    for env in envs:
        for scenario in scenarios:
            cell_seeds = list((seeds_by_scenario or {}).get(scenario, seeds))
            for algo in algos:
                for seed in (cell_seeds if algo in LEARNED_ALGOS else cell_seeds[:1]):
                    run_backend = backend if algo in COMPILED_ALGOS else "sb3"
                    run_bases = () if algo not in RESIDUAL_ALGOS else compiled_bases if run_backend == "jax" else bases
                    out.append(RunSpec(algo, env, scenario, int(seed), int(n_timesteps), ov, test_episodes,
                                       eval_episodes, run_bases, run_backend))
    return out


def status(spec: RunSpec, out: str | Path) -> str:
    """``"done"`` (a sidecar exists), ``"failed"`` (an error file exists) or ``"todo"``."""
    runs = Path(out) / "runs"
    if (runs / f"{spec.stem}.json").exists():
        return "done"
    if (runs / f"{spec.stem}.error").exists():
        return "failed"
    return "todo"
