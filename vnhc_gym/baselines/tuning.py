"""The classical baselines of the comparison, and how their settings are chosen: on validation
episodes only (seeds from 5 000), never on the test episodes (seeds from 10 000).

``CLASSICAL`` names each baseline with its class and its grid of settings; [`tune`][vnhc_gym.baselines.tune] evaluates
every setting on validation episodes and keeps the one with the highest mean ``score`` (the return
over the fixed horizon per step, a terminated episode's remaining steps counting 0:
`vnhc_gym.evaluation.metrics`), so a setting that fails some episodes cannot win on how well it
held the constraint before failing.

``tuned_law`` tunes the law's variant with its gain: the plain law held over the control period
(``phi`` shrinks by about ``1 - k dt`` per period, so it is lost near ``k dt = 2``) or the
sampled-data law, exact for the hold (``exp(-k dt)`` per period at any gain), hence the gains up to
160.  ``safe_law`` is the same family through the safety filter of the task's velocity limits
(`vnhc_gym.baselines.safety`), its ``margin`` and ``rate`` tuned too; on a task without velocity
limits it would be its base, so [`tune`][vnhc_gym.baselines.tune] skips it there
([`applicable`][vnhc_gym.baselines.tuning.applicable]).

``REFERENCE`` holds the headroom references, tuned the same way: ``oracle``, the sampled-data law
on the environment's true state and parameters (`vnhc_gym.baselines.oracle`), and
``informed_kalman``, the Kalman-filter law told the true parameters but not the state
(`vnhc_gym.baselines.kalman`).  They are not controllers one could field, and never a cell's best
classical baseline; the oracle says how far that baseline is from what the law attains with perfect
information, the informed filter how much of that distance is the observations' and how much the
model's.
"""

from __future__ import annotations

import itertools
from typing import Any

from vnhc_gym.baselines.actuated import ActuatedLaw, InformedActuatedLaw
from vnhc_gym.baselines.adaptive import AdaptiveController
from vnhc_gym.baselines.geometric import DEFAULT_GAIN, GeometricController
from vnhc_gym.baselines.kalman import InformedKalmanController, KalmanController
from vnhc_gym.baselines.mpc import MPCController
from vnhc_gym.baselines.observer import ObserverController
from vnhc_gym.baselines.oracle import OracleController
from vnhc_gym.baselines.safety import SafeLaw

__all__ = ["CLASSICAL", "REFERENCE", "SELECTION_METRIC", "applicable", "evaluate_classical", "make_classical",
           "selection_score", "tune"]

#: The metric that settings (and the best classical baseline of a cell) are chosen on: its mean over
#: the validation episodes, higher is better.
SELECTION_METRIC = "score"

#: The law's variants: held over the control period, and the sampled-data law (exact for the hold).
LAW_VARIANTS = ["plain", "sampled"]

#: Baseline name -> (policy class, grid of keyword arguments; every combination is a candidate).
#: ``law`` is the fixed reference (k = 5); the others are tuned per (environment, scenario).  The
#: plain law's high gains and the sampled law's low ones are near-duplicates or losers, kept because
#: a product grid is what the tables and the sweep read, and each costs a fraction of a second.
CLASSICAL: dict[str, tuple[type, dict[str, list[Any]]]] = {
    "law": (GeometricController, {"gain": [DEFAULT_GAIN]}),
    "tuned_law": (GeometricController, {"gain": [1.0, 2.0, 3.0, 5.0, 8.0, 12.0, 20.0, 40.0, 80.0, 160.0],
                                        "variant": LAW_VARIANTS}),
    "safe_law": (SafeLaw, {"gain": [5.0, 20.0, 40.0, 80.0, 160.0], "variant": LAW_VARIANTS,
                           "margin": [0.2, 0.5], "rate": [5.0, 20.0]}),
    "observer": (ObserverController, {"gain": [2.0, 5.0, 10.0], "alpha": [0.3, 0.1, 0.03, 0.01, 0.003]}),
    "kalman": (KalmanController, {"gain": [5.0, 10.0, 20.0, 80.0], "variant": LAW_VARIANTS, "q": [1e-4, 1e-2]}),
    "adaptive": (AdaptiveController, {"gain": [2.0, 5.0, 10.0]}),
    "mpc": (MPCController, {"gain": [2.0, 5.0, 10.0, 20.0], "horizon": [8]}),
    # Where the model is wrong in structure (skipped elsewhere: `ActuatedLaw.applies`): the law on a
    # predictor through the actuator that a bank identifies online, told the range's middle instead,
    # and with a disturbance observer.
    "actuated_law": (ActuatedLaw, {"gain": [2.0, 5.0, 10.0, 20.0, 40.0], "forget": [0.5, 0.8, 0.95]}),
    "actuated_nominal": (ActuatedLaw, {"gain": [2.0, 5.0, 10.0, 20.0, 40.0], "bank": ["nominal"]}),
    "actuated_dob": (ActuatedLaw, {"gain": [5.0, 10.0, 20.0, 40.0], "observer": [0.1, 0.3, 1.0]}),
}
#: The headroom reference, in the same form (the gain of exp(-k dt) per control period).
REFERENCE: dict[str, tuple[type, dict[str, list[Any]]]] = {
    "oracle": (OracleController, {"gain": [2.0, 5.0, 10.0, 20.0, 40.0, 80.0, 160.0]}),
    "informed_kalman": (InformedKalmanController, CLASSICAL["kalman"][1]),
    "informed_actuated": (InformedActuatedLaw, {"gain": [2.0, 5.0, 10.0, 20.0, 40.0, 80.0]}),
}


def make_classical(name: str, env: Any, **kwargs: Any) -> Any:
    """The baseline ``name`` of ``CLASSICAL`` (or the ``REFERENCE``) on ``env`` with the given settings."""
    table = {**CLASSICAL, **REFERENCE}
    if name not in table:
        raise ValueError(f"unknown classical baseline {name!r}; valid: {sorted(table)}")
    cls, _ = table[name]
    policy = cls(env, **kwargs)
    policy.name = name
    return policy


def applicable(name: str, env_id: str, scenario: str = "nominal", **env_kwargs: Any) -> bool:
    """Whether the baseline ``name`` can act differently from its base in a cell: False for the
    safety filter on a task without velocity limits (a class says so with a static ``applies(task)``),
    True for every other baseline."""
    table = {**CLASSICAL, **REFERENCE}
    if name not in table:
        raise ValueError(f"unknown classical baseline {name!r}; valid: {sorted(table)}")
    check = getattr(table[name][0], "applies", None)
    if not callable(check):
        return True
    import gymnasium as gym

    from vnhc_gym.baselines.policy import task_of

    env = gym.make(env_id, scenario=scenario, **env_kwargs)
    try:
        return bool(check(task_of(env)))
    finally:
        env.close()


def evaluate_classical(name: str, settings: dict[str, Any], env_id: str, scenario: str, n_episodes: int, seed: int,
                       built: list[Any] | None = None, **env_kwargs: Any) -> Any:
    """[`evaluate`][vnhc_gym.evaluation.evaluate] of the baseline ``name`` with ``settings`` (built on the
    evaluation's own environment); ``built`` collects the policies built (to read their statistics,
    such as the planning baseline's solve time)."""
    from vnhc_gym.evaluation import evaluate

    def factory(env: Any) -> Any:
        policy = make_classical(name, env, **settings)
        if built is not None:
            built.append(policy)
        return policy

    res = evaluate(factory, env_id, scenario, n_episodes=n_episodes, seed=seed, **env_kwargs)
    res.policy = name
    return res


def selection_score(result: Any) -> float:
    """What settings and checkpoints are chosen on: the mean ``score`` of an evaluation's episodes."""
    return float(result.metrics[SELECTION_METRIC].mean())


def tune(name: str, env_id: str, scenario: str, n_episodes: int = 10, seed: int | None = None,
         **env_kwargs: Any) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """The best settings of baseline ``name`` (of ``CLASSICAL`` or ``REFERENCE``) in one cell, and every
    setting's validation score.

    Returns ``(best_kwargs, table)``; ``table`` rows hold the settings, ``score`` (the mean score over
    the validation episodes, [`selection_score`][vnhc_gym.baselines.tuning.selection_score]) and
    ``success`` (the fraction of them that reached the time limit).  The highest score wins; the
    first setting of the grid wins a tie.  A baseline that is not
    [`applicable`][vnhc_gym.baselines.tuning.applicable] in the cell (the safety filter where the task
    has no velocity limit) is skipped: ``({}, [])``, no episode run.
    """
    from vnhc_gym.evaluation import TEST_SEED, VALIDATION_SEED

    first = VALIDATION_SEED if seed is None else seed
    if first + n_episodes > TEST_SEED:
        raise ValueError(f"tuning episodes (seeds {first}..{first + n_episodes - 1}) must stay below the test seeds "
                         f"({TEST_SEED} and up); pass a smaller seed or n_episodes")
    table_of = {**CLASSICAL, **REFERENCE}
    if name not in table_of:
        raise ValueError(f"unknown classical baseline {name!r}; valid: {sorted(table_of)}")
    if not applicable(name, env_id, scenario, **env_kwargs):
        return {}, []
    _, grid = table_of[name]
    keys = sorted(grid)
    table = []
    for values in itertools.product(*(grid[k] for k in keys)):
        kwargs = dict(zip(keys, values, strict=True))
        res = evaluate_classical(name, kwargs, env_id, scenario, n_episodes, first, **env_kwargs)
        table.append({**kwargs, "score": selection_score(res), "success": float(res.metrics["success"].mean())})
    best = max(table, key=lambda row: row["score"])
    return {k: best[k] for k in keys}, table
