"""The keyword arguments every environment shares, its scenarios and versions, and their checks.

An environment's constructor splits its keyword arguments into an :class:`EnvConfig` (the fields
below, the same for every task) and the task's own options (``current``, ``n_agents``, ...).  A
scenario is a named set of :class:`EnvConfig` overrides; explicit keyword arguments win over it.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Mapping
from dataclasses import dataclass, fields, replace
from typing import Any

import numpy as np

__all__ = ["EnvConfig", "FLOAT32_MAX", "SCENARIOS", "check_integer", "check_number", "check_optional", "configure"]

#: Scenario name -> overrides of :class:`EnvConfig` fields (documented in each env's card).
SCENARIOS: dict[str, dict[str, Any]] = {
    "nominal": {},
    "saturated": {"force_bound_scale": 0.05},
    "mismatch": {"param_mismatch": 0.3},
    "noisy": {"obs_noise": 0.02},
    "coarse": {"dt": 0.1, "substeps": 4},
    "disturbance": {"impulse_prob": 0.05},
}

#: Largest finite float32: observations are float32, so their bound must be below it.
FLOAT32_MAX = float(np.finfo(np.float32).max)

#: Reward shapes: ``"raw"`` is ``clip(-|phi| / phi_scale - action_cost mean(a^2), -reward_clip, 0)``;
#: ``"bounded"`` is ``exp(-|phi~| / reward_sigma) - action_cost mean(a^2)`` in ``[0, 1]`` with the
#: task's scale-free ``|phi~|``.
REWARDS = ("raw", "bounded")


def check_optional(name: str, value: Any, **bounds: Any) -> float | None:
    """:func:`check_number` that also accepts ``None`` (and returns it)."""
    return None if value is None else check_number(name, value, allow_none=True, **bounds)


def check_number(name: str, value: Any, *, low: float | None = None, high: float | None = None,
                 low_open: bool = False, allow_none: bool = False) -> float:
    """``value`` as a float if it is a finite real number in the given range, else a ``ValueError``
    (``TypeError`` for something that is not a number) naming ``name``, the value and what is
    expected (``allow_none`` only changes the message; use :func:`check_optional` to accept None)."""
    bounds = []
    if low is not None:
        bounds.append(f"{'>' if low_open else '>='} {low:g}")
    if high is not None:
        bounds.append(f"<= {high:g}")
    want = "a finite number" + (" " + " and ".join(bounds) if bounds else "") + (" or None" if allow_none else "")
    if isinstance(value, bool | np.bool_) or not isinstance(value, numbers.Real):
        raise TypeError(f"{name} must be {want}, got {value!r} of type {type(value).__name__}")
    try:
        x = float(value)
    except (OverflowError, ValueError):
        raise ValueError(f"{name} must be {want}, got {value!r}") from None
    if not math.isfinite(x) or (low is not None and (x <= low if low_open else x < low)) or \
            (high is not None and x > high):
        raise ValueError(f"{name} must be {want}, got {value!r}")
    return x


def check_integer(name: str, value: Any, *, low: int, high: int | None = None) -> int:
    """``value`` as an int if it is an integer in ``[low, high]``, else an error naming ``name``."""
    want = f"an integer >= {low}" + (f" and <= {high}" if high is not None else "")
    if isinstance(value, bool | np.bool_) or not isinstance(value, numbers.Integral):
        raise TypeError(f"{name} must be {want}, got {value!r} of type {type(value).__name__}")
    if int(value) < low or (high is not None and int(value) > high):
        raise ValueError(f"{name} must be {want}, got {value!r}")
    return int(value)


@dataclass(frozen=True)
class EnvConfig:
    """Keyword arguments common to every environment (see the env cards).

    Attributes
    ----------
    dt : float
        Control period in seconds (the action is held over it).
    substeps : int
        RK4 steps per control period.
    force_bound : float or None
        Largest absolute force of each control (``None``: the task's default).
    force_bound_scale : float
        Multiplies ``force_bound`` (the ``saturated`` scenario uses 0.05).
    reward : {"raw", "bounded"}
        The reward's shape (see ``REWARDS``).
    phi_scale : float
        ``|phi|`` is divided by this in the raw reward.
    reward_sigma : float or None
        Width of the bounded reward ``exp(-|phi~| / reward_sigma)`` (``None``: the task's default).
    action_cost : float
        Weight ``c_u`` of ``mean(a^2)`` in the reward.
    reward_clip : float
        Raw rewards are clipped to ``[-reward_clip, 0]`` (a diverging episode cannot dominate a batch).
    param_mismatch : float
        Relative half-width ``delta``: each episode the true physical parameters are the nominal
        ones times ``U(1 - delta, 1 + delta)`` (independently per parameter).
    obs_noise : float
        Standard deviation of Gaussian noise added to every observation entry.
    impulse_prob : float
        Probability per step of a random velocity impulse.
    impulse_scale : float or None
        Standard deviation of an impulse's velocity change (``None``: the task's default).
    obs_clip : float
        Observations are clipped to ``[-obs_clip, obs_clip]`` (the observation space).
    """

    dt: float = 0.05
    substeps: int = 1
    force_bound: float | None = None
    force_bound_scale: float = 1.0
    reward: str = "bounded"
    phi_scale: float = 1.0
    reward_sigma: float | None = None
    action_cost: float = 0.0
    reward_clip: float = 100.0
    param_mismatch: float = 0.0
    obs_noise: float = 0.0
    impulse_prob: float = 0.0
    impulse_scale: float | None = None
    obs_clip: float = 10.0

    def checked(self) -> EnvConfig:
        """A copy with every field checked and converted (``ValueError``/``TypeError`` naming the
        first bad argument)."""
        if self.reward not in REWARDS:
            raise ValueError(f"reward must be one of {list(REWARDS)}, got {self.reward!r}")
        return replace(
            self,
            dt=check_number("dt", self.dt, low=0.0, low_open=True, high=1e6),
            substeps=check_integer("substeps", self.substeps, low=1, high=100_000),
            force_bound=check_optional("force_bound", self.force_bound, low=0.0, low_open=True, high=1e12),
            force_bound_scale=check_number("force_bound_scale", self.force_bound_scale, low=0.0, low_open=True,
                                           high=1e6),
            phi_scale=check_number("phi_scale", self.phi_scale, low=0.0, low_open=True),
            reward_sigma=check_optional("reward_sigma", self.reward_sigma, low=0.0, low_open=True),
            action_cost=check_number("action_cost", self.action_cost, low=0.0),
            reward_clip=check_number("reward_clip", self.reward_clip, low=0.0, low_open=True, high=1e30),
            param_mismatch=check_number("param_mismatch", self.param_mismatch, low=0.0, high=0.99),
            obs_noise=check_number("obs_noise", self.obs_noise, low=0.0, high=1e6),
            impulse_prob=check_number("impulse_prob", self.impulse_prob, low=0.0, high=1.0),
            impulse_scale=check_optional("impulse_scale", self.impulse_scale, low=0.0, low_open=True, high=1e6),
            obs_clip=check_number("obs_clip", self.obs_clip, low=0.0, low_open=True, high=FLOAT32_MAX),
        )


CONFIG_FIELDS: tuple[str, ...] = tuple(f.name for f in fields(EnvConfig))


def configure(scenario: Any, kwargs: Mapping[str, Any], options: Mapping[str, Any],
              defaults: Mapping[str, Any] | None = None) -> tuple[EnvConfig, dict[str, Any]]:
    """Split an environment's keyword arguments into a checked :class:`EnvConfig` and task options.

    Parameters
    ----------
    scenario : str
        A name of ``SCENARIOS``; its overrides come first, then ``kwargs``.
    kwargs : mapping
        The constructor's keyword arguments.
    options : mapping
        The task's own option names and their defaults.
    defaults : mapping, optional
        The version's defaults of :class:`EnvConfig` fields (e.g. the reward of ``-v1``), applied
        before the scenario.

    Returns
    -------
    (config, task_options)
        ``task_options`` holds every name of ``options``, with the caller's value or the default.
    """
    if not isinstance(scenario, str) or scenario not in SCENARIOS:
        raise ValueError(f"scenario must be one of {sorted(SCENARIOS)}, got {scenario!r}")
    unknown = sorted(k for k in kwargs if k not in CONFIG_FIELDS and k not in options)
    if unknown:
        raise ValueError(f"unknown keyword argument(s) {unknown}; valid: "
                         f"{sorted(['scenario', 'render_mode', *CONFIG_FIELDS, *options])}")
    own = {k: v for k, v in kwargs.items() if k in CONFIG_FIELDS}
    config = replace(EnvConfig(), **{**dict(defaults or {}), **SCENARIOS[scenario], **own}).checked()
    return config, {k: kwargs.get(k, v) for k, v in options.items()}
