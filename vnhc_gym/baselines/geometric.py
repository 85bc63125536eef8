"""The geometric stabilising law as a policy that sees only the observation, for any task.

The task says how to read the state back from an observation and which (nominal) model a
controller may use ([`controller_inputs`][vnhc_gym.tasks.base.Task.controller_inputs]); the law itself is the
core's [`control`][vnhc_gym.mechanics.ConstrainedSystem.control], ``u* = C^-1 (-K phi - G(phi))``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from vnhc_gym.baselines.policy import Policy, checked_task_of
from vnhc_gym.mechanics import sampled_control

__all__ = ["DEFAULT_GAIN", "GeometricController", "StatefulLaw"]

#: Default gain k of the baseline.  The paper uses K = I with continuous feedback; held over the
#: environments' 0.05 s control period, k = 5 (time constant 0.2 s, four control periods,
#: k dt = 0.5 even at the coarse 0.1 s) converges 5x faster and stays well inside the zero-order
#: hold's stability range.
DEFAULT_GAIN = 5.0

Array = NDArray[np.float64]


class GeometricController(Policy):
    """The stabilising law computed from the observation and the nominal model (SB3 ``predict``).

    Parameters
    ----------
    env : gymnasium Env or VectorEnv
        A vnhc_gym environment (possibly wrapped, or vector); its task (the nominal model, the force
        bound, ``dt`` and ``substeps``) is read once, here.  The action depends on the observation
        only.
    gain : float or array_like, default ``DEFAULT_GAIN`` (5)
        ``diag K`` (one value per constraint component, or a scalar).
    variant : {"plain", "sampled"}
        ``"plain"``: ``u*`` at the observed state, held over the control period.  ``"sampled"``: the
        held control that makes ``phi`` after one period of the nominal RK4 step map equal
        ``exp(-K dt) phi`` ([`vnhc_gym.mechanics.sampled_control`][vnhc_gym.mechanics.sampled_control]).
    iters : int, default 4
        Newton iterations of the sampled variant.

    Attributes
    ----------
    last_singular, last_saturated : ndarray of bool
        Per row of the last batch: ``C`` was singular (the action is 0 there), or the law asked for
        more than the force bound (the action was clipped).
    n_singular, n_saturated, n_rows : int
        Running counts.
    """

    def __init__(self, env: Any, gain: ArrayLike = DEFAULT_GAIN, variant: str = "plain", *, iters: int = 4) -> None:
        if variant not in ("plain", "sampled"):
            raise ValueError(f"variant must be 'plain' or 'sampled', got {variant!r}")
        task = checked_task_of(env)
        self.task = task
        self.model = task.controller_model()
        self.obs_dim = task.obs_dim
        self.act_dim = task.act_dim
        self.variant = variant
        self.name = "geometric" if variant == "plain" else "geometric-sampled"
        k = np.asarray(gain, dtype=np.float64)
        if k.ndim > 1 or (k.ndim == 1 and k.shape[0] != self.model.n_gains) or not np.all(np.isfinite(k)) \
                or np.any(k < 0):
            raise ValueError(f"gain must be a finite number >= 0 or {self.model.n_gains} of them, got {gain!r}")
        self.gain = np.broadcast_to(k, (self.model.n_gains,)).copy()
        if isinstance(iters, bool) or not isinstance(iters, int | np.integer) or iters < 0:
            raise ValueError(f"iters must be an integer >= 0, got {iters!r}")
        self.iters = int(iters)
        self.force_bound = task.force_bound
        self.dt = task.config.dt
        self.substeps = task.config.substeps
        self.last_singular = np.zeros(0, dtype=bool)
        self.last_saturated = np.zeros(0, dtype=bool)
        self.n_singular = self.n_saturated = self.n_rows = 0

    def __repr__(self) -> str:
        return f"GeometricController({self.task.name!r}, variant={self.variant!r}, gain={self.gain.tolist()})"

    def law(self, states: Array, params: Array) -> tuple[Array, NDArray[np.bool_]]:
        """``u*`` of the controller's model and the singular rows; a row whose state or parameters are
        not finite or not valid (an estimate gone astray) gets ``u = 0`` and is flagged, so a
        policy never raises in the middle of an episode."""
        good = np.asarray(np.isfinite(states).all(axis=1) & np.isfinite(params).all(axis=1), dtype=bool)
        positive = getattr(self.model, "param_positive", None)
        if positive is not None and np.any(positive):
            good &= np.all(params[:, np.asarray(positive, dtype=bool)] > 0, axis=1)
        if good.all():
            u_all, sing_all = self.model.control(states, self.gain, params, on_singular="flag")
            return u_all, np.asarray(sing_all)
        u = np.zeros((states.shape[0], self.act_dim))
        singular = np.logical_not(good)
        if good.any():
            u[good], sing = self.model.control(states[good], self.gain, params[good], on_singular="flag")
            singular[good] = np.asarray(sing)
        return u, singular

    def force(self, obs: ArrayLike) -> tuple[Array, NDArray[np.bool_]]:
        """The unsaturated force ``u`` (N) of the chosen variant and the singular rows, for a batch of
        observations."""
        o, _ = self.check_obs(obs)
        states, params = self.task.controller_inputs(o)
        u, singular = self.law(states, params)
        return self.held(u, singular, states, params), np.asarray(singular)

    def held(self, u: Array, singular: NDArray[np.bool_], states: Array, params: Array) -> Array:
        """The force to hold over the control period: ``u`` (the law) for the plain variant; for the
        sampled one, the sampled-data law from ``u`` where it converges (``u`` elsewhere)."""
        if self.variant == "sampled":
            ok = ~np.asarray(singular)
            if ok.any():
                us, _ = sampled_control(self.model, states[ok], params[ok], self.dt, self.gain, self.substeps,
                                        self.iters)
                u[ok] = np.where(np.isfinite(us), us, u[ok])
        return u

    def act(self, obs: Array) -> Array:
        u, singular = self.force(obs)
        a = u / self.force_bound
        bad = ~np.isfinite(a)
        if bad.any():  # a singular C gives u = 0; this keeps the contract for any observation
            a[bad] = 0.0
            singular = singular | bad.any(axis=1)
        saturated = np.any(np.abs(a) > 1.0, axis=1)
        self.last_singular, self.last_saturated = singular, saturated
        self.n_singular += int(singular.sum())
        self.n_saturated += int(saturated.sum())
        self.n_rows += a.shape[0]
        return np.clip(a, -1.0, 1.0)


class StatefulLaw(GeometricController):
    """The law with an internal estimate carried from step to step (the observer and adaptive laws).

    A subclass keeps ``_u`` (the force applied since its last estimate, ``(B, m)``, or None before
    the first one) and ``_fresh`` (rows whose next observation starts a new episode); this class
    keeps both in step with the environment.
    """

    _u: NDArray[np.float64] | None = None
    _fresh: NDArray[np.bool_] | None = None
    _estimate: tuple[Array, Array] | None = None  # the states and parameters the last action used
    keeps_estimate = True

    def belief(self, obs: Array) -> Array:
        """The observations of the estimate the last action used (the task's
        [`observation_of`][vnhc_gym.tasks.base.Task.observation_of]), clipped to the observation
        space; ``obs`` where that frame holds no value (a boat's position in its own frame) and
        before the first action."""
        o = np.asarray(obs, dtype=np.float64).reshape(-1, self.obs_dim)
        if self._estimate is None or self._estimate[0].shape[0] != o.shape[0]:
            return o
        seen = self.task.observation_of(*self._estimate)
        bound = self.task.config.obs_clip
        return np.where(np.isfinite(seen), np.clip(seen, -bound, bound), o)

    def reset_rows(self, rows: NDArray[np.bool_]) -> None:
        if self._fresh is not None and self._fresh.shape == rows.shape:
            self._fresh |= rows

    def applied(self, action: ArrayLike) -> None:
        """Predict the next state with the force the environment received (see
        [`Policy.applied`][vnhc_gym.baselines.Policy.applied])."""
        if self._u is None:
            return
        a = np.asarray(action, dtype=np.float64).reshape(self._u.shape)
        self._u = np.clip(np.where(np.isfinite(a), a, 0.0), -1.0, 1.0) * self.force_bound
