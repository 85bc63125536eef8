"""The keyword arguments every environment shares, its scenarios and versions, and their checks.

An environment's constructor splits its keyword arguments into an [`EnvConfig`][vnhc_gym.envs.EnvConfig] (the fields
below, the same for every task) and the task's own options (``current``, ``n_agents``, ...).  A
scenario is a named set of [`EnvConfig`][vnhc_gym.envs.EnvConfig] overrides; explicit keyword arguments win over it.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Mapping
from dataclasses import dataclass, field, fields, replace
from typing import Any, TypeVar

import numpy as np

__all__ = ["EnvConfig", "FLOAT32_MAX", "MAX_DELAY", "SCENARIOS", "STRUCTURAL", "TaskOptions", "check_choice",
           "check_flag", "check_integer", "check_number", "check_optional", "configure", "option"]

#: Scenario name -> overrides of [`EnvConfig`][vnhc_gym.envs.EnvConfig] fields (documented in each env's card).
SCENARIOS: dict[str, dict[str, Any]] = {
    "nominal": {},
    "saturated": {"force_bound_scale": 0.05},
    "mismatch": {"param_mismatch": 0.3},
    "noisy": {"obs_noise": 0.02},
    "coarse": {"dt": 0.1, "substeps": 4},
    "disturbance": {"impulse_prob": 0.05},
    # The model wrong in structure: each hidden from the controller, drawn per episode and drawn
    # again once at a random step (identification is never done once and for all).
    "delay": {"delay_min": 2, "delay_max": 6, "redraw": True},
    "lag": {"lag_min": 0.1, "lag_max": 0.5, "redraw": True},
    "unmodelled": {"unmodelled": 1.0, "redraw": True},
}

#: The scenarios whose model is wrong in structure (an actuator the model lacks, forces it lacks).
STRUCTURAL = ("delay", "lag", "unmodelled")

#: Largest delay (control periods) an environment holds commands for.
MAX_DELAY = 100

#: Largest finite float32: observations are float32, so their bound must be below it.
FLOAT32_MAX = float(np.finfo(np.float32).max)

#: Reward shapes: ``"raw"`` is ``clip(-|phi| / phi_scale - action_cost mean(a^2), -reward_clip, 0)``;
#: ``"bounded"`` is ``exp(-|phi~| / reward_sigma) - action_cost mean(a^2)`` in ``[0, 1]`` with the
#: task's scale-free ``|phi~|``; ``"reciprocal"`` is ``1 / (1 + |phi~| / reward_sigma) - action_cost
#: mean(a^2)`` in ``[0, 1]``: the same value and slope as ``"bounded"`` at ``phi~ = 0``, but a long
#: tail (``sigma / |phi~|`` far away, where the exponential is numerically 0), dm_control's
#: ``tolerance(..., sigmoid="reciprocal", value_at_margin=0.5)`` with the margin ``reward_sigma``.
REWARDS = ("raw", "bounded", "reciprocal")


def check_optional(name: str, value: Any, **bounds: Any) -> float | None:
    """`check_number` that also accepts ``None`` (and returns it)."""
    return None if value is None else check_number(name, value, allow_none=True, **bounds)


def check_number(name: str, value: Any, *, low: float | None = None, high: float | None = None,
                 low_open: bool = False, allow_none: bool = False) -> float:
    """``value`` as a float if it is a finite real number in the given range, else a ``ValueError``
    (``TypeError`` for something that is not a number) naming ``name``, the value and what is
    expected (``allow_none`` only changes the message; use `check_optional` to accept None)."""
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


def check_flag(name: str, value: Any) -> bool:
    """``value`` if it is a bool, else a ``TypeError`` naming ``name``."""
    if not isinstance(value, bool | np.bool_):
        raise TypeError(f"{name} must be True or False, got {value!r} of type {type(value).__name__}")
    return bool(value)


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
    reward : {"raw", "bounded", "reciprocal"}
        The reward's shape (see ``REWARDS``).
    phi_scale : float
        ``|phi|`` is divided by this in the raw reward.
    reward_sigma : float or None
        Width of the bounded reward ``exp(-|phi~| / reward_sigma)`` (or of the reciprocal one;
        ``None``: the task's default).
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
    delay_min, delay_max : int
        Each episode the force applied is the one commanded ``d`` control periods earlier, ``d``
        uniform in ``[delay_min, delay_max]`` (0: none; the commands before the start are 0).
    lag_min, lag_max : float
        Each episode the actuator is a first-order lag whose time constant (s) is drawn
        log-uniformly in ``[lag_min, lag_max]`` (0: none): over a period the force it applies is its
        state's mean while that state relaxes towards the command (it starts at 0).
    unmodelled : float
        Scale of the task's forces that the nominal model lacks (0: none; 1: the coefficients of the
        task's card, drawn per episode).
    redraw : bool
        The hidden quantities (the delay, the time constant, the unmodelled coefficients) are drawn
        again once, at a step uniform over the middle half of the episode.
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
    delay_min: int = 0
    delay_max: int = 0
    lag_min: float = 0.0
    lag_max: float = 0.0
    unmodelled: float = 0.0
    redraw: bool = False

    @property
    def structural(self) -> bool:
        """Whether the episodes carry hidden structure (a delay, a lag or unmodelled forces)."""
        return self.delay_max > 0 or self.lag_max > 0 or self.unmodelled > 0

    def checked(self) -> EnvConfig:
        """A copy with every field checked and converted (``ValueError``/``TypeError`` naming the
        first bad argument)."""
        if self.reward not in REWARDS:
            raise ValueError(f"reward must be one of {list(REWARDS)}, got {self.reward!r}")
        delay_min = check_integer("delay_min", self.delay_min, low=0, high=MAX_DELAY)
        lag_min = check_number("lag_min", self.lag_min, low=0.0, high=1e3)
        if self.lag_max and not lag_min:
            raise ValueError(f"lag_min must be > 0 when lag_max is set (the time constant is drawn log-uniformly), "
                             f"got lag_min={self.lag_min!r}, lag_max={self.lag_max!r}")
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
            delay_min=delay_min,
            delay_max=check_integer("delay_max", self.delay_max, low=delay_min, high=MAX_DELAY),
            lag_min=lag_min,
            lag_max=check_number("lag_max", self.lag_max, low=lag_min, high=1e3),
            unmodelled=check_number("unmodelled", self.unmodelled, low=0.0, high=1e3),
            redraw=check_flag("redraw", self.redraw),
        )


CONFIG_FIELDS: tuple[str, ...] = tuple(f.name for f in fields(EnvConfig))


def check_choice(name: str, value: Any, choices: Any, allow_none: bool = False) -> Any:
    """``value`` if it is one of ``choices`` (or ``None`` with ``allow_none``), else a ``ValueError``
    naming ``name``, the value and the valid choices."""
    if allow_none and value is None:
        return None
    valid = sorted(choices)
    try:
        ok = isinstance(value, str) and value in valid if all(isinstance(c, str) for c in valid) else value in valid
    except TypeError:
        ok = False
    if not ok:
        raise ValueError(f"{name} must be one of {valid}{' or None' if allow_none else ''}, got {value!r}")
    return value


def option(default: Any, doc: str, *, low: float | None = None, high: float | None = None, low_open: bool = False,
           integer: bool = False, choices: Any = None, allow_none: bool = False) -> Any:
    """One field of a task's [`TaskOptions`][vnhc_gym.envs.TaskOptions]: its default, what it means
    (with units), and how it is checked.

    ``choices`` checks membership (`check_choice`), ``integer`` an integer in ``[low, high]``
    (`check_integer`), and otherwise ``low``/``high``/``low_open`` bound a finite number
    (`check_number`); ``allow_none`` also accepts ``None``.  A field with none of these is
    the task's to check (a list or a dict, say): its constructor does it with the same helpers.
    """
    check: dict[str, Any] | None = None
    if choices is not None:
        check = {"kind": "choice", "choices": tuple(choices), "allow_none": allow_none}
    elif integer:
        check = {"kind": "integer", "low": int(low if low is not None else 0), "high": high}
    elif low is not None or high is not None:
        check = {"kind": "number", "low": low, "high": high, "low_open": low_open, "allow_none": allow_none}
    return field(default=default, metadata={"doc": doc, "check": check})


_Options = TypeVar("_Options", bound="TaskOptions")


@dataclass(frozen=True)
class TaskOptions:
    """The keyword arguments of one task, declared once: subclass it as a frozen dataclass whose
    fields are made with [`option`][vnhc_gym.envs.option].

    The environment's constructor takes these names besides [`EnvConfig`][vnhc_gym.envs.EnvConfig]'s, fills in the
    defaults, checks every declared field by name
    ([`checked`][vnhc_gym.envs.config.TaskOptions.checked]) and hands the result to the task's
    constructor; the test suite holds the env card's Arguments table to the same fields.
    """

    def checked(self: _Options) -> _Options:
        """A copy with every field that declares a check checked and converted (``ValueError`` or
        ``TypeError`` naming the field)."""
        changes: dict[str, Any] = {}
        for f in fields(self):
            check = f.metadata.get("check")
            value = getattr(self, f.name)
            if check is None:
                continue
            kind = check["kind"]
            if kind == "choice":
                changes[f.name] = check_choice(f.name, value, check["choices"], check["allow_none"])
            elif kind == "integer":
                changes[f.name] = check_integer(f.name, value, low=check["low"], high=check["high"])
            elif check["allow_none"]:
                changes[f.name] = check_optional(f.name, value, low=check["low"], high=check["high"],
                                                 low_open=check["low_open"])
            else:
                changes[f.name] = check_number(f.name, value, low=check["low"], high=check["high"],
                                               low_open=check["low_open"])
        return replace(self, **changes)

    @classmethod
    def defaults(cls) -> dict[str, Any]:
        """Every option's name and default."""
        return {f.name: f.default for f in fields(cls)}

    @classmethod
    def docs(cls) -> dict[str, str]:
        """Every option's name and meaning (what the env card's Arguments table says)."""
        return {f.name: str(f.metadata.get("doc", "")) for f in fields(cls)}


def configure(scenario: Any, kwargs: Mapping[str, Any], options: type[_Options],
              defaults: Mapping[str, Any] | None = None,
              magnitudes: Mapping[str, Mapping[str, Any]] | None = None) -> tuple[EnvConfig, _Options]:
    """Split an environment's keyword arguments into a checked [`EnvConfig`][vnhc_gym.envs.EnvConfig] and task options.

    Parameters
    ----------
    scenario : str
        A name of ``SCENARIOS``; its overrides come first, then ``kwargs``.
    kwargs : mapping
        The constructor's keyword arguments.
    options : type of TaskOptions
        The task's own options.
    defaults : mapping, optional
        The version's defaults of [`EnvConfig`][vnhc_gym.envs.EnvConfig] fields (e.g. the reward of ``-v1``), applied
        before the scenario.
    magnitudes : mapping, optional
        The task's own values of a scenario's fields (``Task.scenario_magnitudes``), over ``SCENARIOS``'.

    Returns
    -------
    (config, task_options)
        ``task_options`` is an ``options`` instance with the caller's values or the defaults, checked.
    """
    if not isinstance(scenario, str) or scenario not in SCENARIOS:
        raise ValueError(f"scenario must be one of {sorted(SCENARIOS)}, got {scenario!r}")
    names = options.defaults()
    unknown = sorted(k for k in kwargs if k not in CONFIG_FIELDS and k not in names)
    if unknown:
        raise ValueError(f"unknown keyword argument(s) {unknown}; valid: "
                         f"{sorted(['scenario', 'render_mode', *CONFIG_FIELDS, *names])}")
    own = {k: v for k, v in kwargs.items() if k in CONFIG_FIELDS}
    scenario_fields = {**SCENARIOS[scenario], **dict((magnitudes or {}).get(scenario, {}))}
    config = replace(EnvConfig(), **{**dict(defaults or {}), **scenario_fields, **own}).checked()
    return config, options(**{k: v for k, v in kwargs.items() if k in names}).checked()
