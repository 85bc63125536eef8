"""What a task is: the one definition that the environments, baselines, training and evaluation read.

A task module (``vnhc_gym/tasks/usv.py`` is one) holds, in this order:

1. two compiled hooks, ``draw`` (a new episode of one row) and ``observe`` (a row's observation,
   status and scale-free ``phi``), with ``DRAW_STAGES``; their signatures are those of
   :mod:`vnhc_gym.envs._placeholder`;
2. a :class:`Task` subclass: the mechanical system and constraint, the task's own options, the
   constants the hooks read (``args``), the observation size, the default force bound, the
   termination reasons, and how a controller reads the state back from an observation;
3. the environment class with its card (a subclass of :class:`~vnhc_gym.envs.env.ConstraintEnv`)
   and its native vector version.

One line in :mod:`vnhc_gym.tasks` registers it.
"""

from __future__ import annotations

from typing import Any, ClassVar, NamedTuple

import numpy as np
from numpy.typing import NDArray

from vnhc_gym.envs.config import EnvConfig
from vnhc_gym.envs.episode import StepConfig
from vnhc_gym.mechanics import FEEDBACK_MODES, ConstrainedSystem

__all__ = ["Task"]

Array = NDArray[np.float64]


class Task:
    """A virtual-constraint task configured for one environment (subclass once per task).

    Class attributes (the definition)
    ---------------------------------
    name : str
        Registry name (``"usv"``).
    options : dict
        The task's own constructor arguments and their defaults (besides :class:`EnvConfig`'s).
    reasons : tuple of str
        Termination reasons of the task's ``observe`` (status codes ``TASK_STATUS + i``);
        ``"non_finite_state"`` is common to every task.
    default_force_bound : float
        Force (N) of action 1 when ``force_bound`` is not given.
    default_impulse_scale : float
        Standard deviation (m/s) of a velocity impulse when ``impulse_scale`` is not given.
    reward_sigma : float
        Width of the bounded reward ``exp(-|phi~| / sigma)`` when ``reward_sigma`` is not given.
    phi_units, phi_sf_meaning : str
        Units of ``phi`` and what the scale-free ``phi~`` is, for tables and docs.

    Instance attributes (set by the subclass's constructor)
    --------------------------------------------------------
    config : EnvConfig
    model : ConstrainedSystem
        The compiled system with the constraint, the environment's dynamics.
    nominal : ndarray
        The nominal parameter vector of ``model`` (what a controller is told).
    args : NamedTuple
        The constants the hooks read (``observe(r, buf, cfg, args)``).
    obs_dim : int
    impulse_mask : ndarray, shape (n,)
        Weights of the velocity entries that impulses kick (0 = never).
    """

    name: ClassVar[str]
    options: ClassVar[dict[str, Any]] = {}
    reasons: ClassVar[tuple[str, ...]] = ()
    default_force_bound: ClassVar[float]
    default_impulse_scale: ClassVar[float]
    reward_sigma: ClassVar[float] = 0.1
    phi_units: ClassVar[str] = ""
    phi_sf_meaning: ClassVar[str] = ""
    #: Indices of the controller state (:meth:`controller_inputs`) that are angles: an observer
    #: takes their differences modulo 2 pi.
    angles: ClassVar[tuple[int, ...]] = ()
    #: Names of the parameters the ``mismatch`` scenario perturbs (an adaptive controller estimates
    #: them), in :meth:`controller_model`'s parameter names.
    uncertain: ClassVar[tuple[str, ...]] = ()

    config: EnvConfig
    model: ConstrainedSystem
    nominal: Array
    args: NamedTuple
    obs_dim: int
    impulse_mask: Array

    @property
    def act_dim(self) -> int:
        """Number of controls (= action entries = constraint components)."""
        return self.model.m

    @property
    def force_bound(self) -> Array:
        """Force (N) of action 1, per control: ``force_bound * force_bound_scale``."""
        bound = self.config.force_bound if self.config.force_bound is not None else self.default_force_bound
        return np.full(self.act_dim, bound * self.config.force_bound_scale)

    @property
    def all_reasons(self) -> tuple[str | None, ...]:
        """``termination_reason`` by status code (None for "no termination")."""
        return (None, "non_finite_state", *self.reasons)

    def step_config(self, feedback: str = "open", gains: Any = 1.0) -> StepConfig:
        """The step's named scalars, from the configuration (``feedback``/``gains``: the in-loop law of
        :meth:`~vnhc_gym.envs.runtime.Batch.set_feedback`)."""
        c = self.config
        if feedback not in FEEDBACK_MODES:
            raise ValueError(f"feedback must be one of {sorted(FEEDBACK_MODES)}, got {feedback!r}")
        k = np.broadcast_to(np.asarray(gains, dtype=np.float64), (self.model.n_gains,)).copy()
        if not (np.all(np.isfinite(k)) and np.all(k >= 0)):
            raise ValueError(f"gains must be finite and >= 0, got {gains!r}")
        bound = self.force_bound
        return StepConfig(
            dt=c.dt, substeps=c.substeps, bound=bound, lo=-bound, hi=bound.copy(), mode=FEEDBACK_MODES[feedback],
            gains=k, singular_tol=self.model.singular_tol, bounded=c.reward == "bounded", phi_scale=c.phi_scale,
            reward_sigma=self.reward_sigma if c.reward_sigma is None else c.reward_sigma,
            action_cost=c.action_cost, reward_clip=c.reward_clip, obs_noise=c.obs_noise, obs_clip=c.obs_clip,
            impulse_prob=c.impulse_prob,
            impulse_scale=self.default_impulse_scale if c.impulse_scale is None else c.impulse_scale,
            impulse_mask=self.impulse_mask)

    # ------------------------------------------------------------------ what a controller reads
    def controller_model(self) -> ConstrainedSystem:
        """The model a model-based controller uses (default: the environment's own system)."""
        return self.model

    def controller_inputs(self, obs: Array) -> tuple[Array, Array]:
        """States and parameters of :meth:`controller_model` rebuilt from observations ``(B, d)``.

        The parameters are the nominal ones (a controller is never told the true ones); entries
        the law does not depend on (positions of free-falling particles, say) may be zero.
        """
        raise NotImplementedError

    def recenter(self, states: Array, params: Array) -> tuple[Array, Array]:
        """Controller states and parameters predicted one step ahead, expressed in the frame of the
        next :meth:`controller_inputs` (identity unless that frame moves with the system)."""
        return states, params

    def describe(self) -> dict[str, Any]:
        """A JSON-friendly summary of the configured task (for result files)."""
        return {"task": self.name, "config": {k: getattr(self.config, k) for k in self.config.__dataclass_fields__},
                "force_bound": self.force_bound.tolist(), "obs_dim": self.obs_dim, "act_dim": self.act_dim}
