"""The classical baselines of the comparison, and how their settings are chosen: on validation
episodes only (seeds from 5 000), never on the test episodes (seeds from 10 000).

``CLASSICAL`` names each baseline with its class and its grid of settings; :func:`tune` evaluates
every setting on validation episodes and keeps the one with the lowest interquartile mean of the
per-episode scale-free ``mean |phi~|``.
"""

from __future__ import annotations

import itertools
from typing import Any

from vnhc_gym.baselines.adaptive import AdaptiveController
from vnhc_gym.baselines.geometric import DEFAULT_GAIN, GeometricController
from vnhc_gym.baselines.observer import ObserverController

__all__ = ["CLASSICAL", "SELECTION_METRIC", "make_classical", "tune"]

#: The metric that settings (and the best classical baseline of a cell) are chosen on.
SELECTION_METRIC = "mean_abs_phi_sf"

#: Baseline name -> (policy class, grid of keyword arguments).  ``law`` is the fixed reference
#: (k = 5); the others are tuned per (environment, scenario).
CLASSICAL: dict[str, tuple[type, dict[str, list[Any]]]] = {
    "law": (GeometricController, {"gain": [DEFAULT_GAIN]}),
    "tuned_law": (GeometricController, {"gain": [1.0, 2.0, 3.0, 5.0, 8.0, 12.0, 20.0]}),
    "observer": (ObserverController, {"gain": [2.0, 5.0, 10.0], "alpha": [0.3, 0.1, 0.03, 0.01, 0.003]}),
    "adaptive": (AdaptiveController, {"gain": [2.0, 5.0, 10.0]}),
}


def make_classical(name: str, env: Any, **kwargs: Any) -> Any:
    """The baseline ``name`` of ``CLASSICAL`` on ``env`` with the given settings."""
    if name not in CLASSICAL:
        raise ValueError(f"unknown classical baseline {name!r}; valid: {sorted(CLASSICAL)}")
    cls, _ = CLASSICAL[name]
    policy = cls(env, **kwargs)
    policy.name = name
    return policy


def tune(name: str, env_id: str, scenario: str, n_episodes: int = 10, seed: int | None = None,
         **env_kwargs: Any) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """The best settings of baseline ``name`` in one cell, and every setting's validation score.

    Returns ``(best_kwargs, table)``; ``table`` rows hold the settings and the IQM of
    ``SELECTION_METRIC`` over the validation episodes.
    """
    from vnhc_gym.evaluation import TEST_SEED, VALIDATION_SEED, evaluate

    first = VALIDATION_SEED if seed is None else seed
    if first + n_episodes > TEST_SEED:
        raise ValueError(f"tuning episodes (seeds {first}..{first + n_episodes - 1}) must stay below the test seeds "
                         f"({TEST_SEED} and up); pass a smaller seed or n_episodes")
    _, grid = CLASSICAL[name]
    keys = sorted(grid)
    table = []
    for values in itertools.product(*(grid[k] for k in keys)):
        kwargs = dict(zip(keys, values, strict=True))
        def factory(env: Any, kw: dict[str, Any] = kwargs) -> Any:
            return make_classical(name, env, **kw)

        res = evaluate(factory, env_id, scenario, n_episodes=n_episodes, seed=first, **env_kwargs)
        table.append({**kwargs, "score": res.summary(reps=200)[SELECTION_METRIC].point})
    best = min(table, key=lambda row: row["score"])
    return {k: best[k] for k in keys}, table
