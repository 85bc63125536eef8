"""``vnhc_gym/USVStream-v0``: hold a boat in a sea current to an affine velocity constraint."""

from __future__ import annotations

import math
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from numba import njit
from numpy.typing import NDArray

from vnhc_gym.envs._random import normal_pair, sign, uniform_ab
from vnhc_gym.envs.base import ConstraintEnv
from vnhc_gym.envs.task import (
    STATUS_INVALID,
    STATUS_NONFINITE,
    STATUS_OK,
    STATUS_SPIN,
    ConstraintTask,
    ObserveKernels,
    TaskConfig,
    _is_real,
    draw_mismatch,
    finish_rows,
    reject_unknown,
    resolve_config,
)
from vnhc_gym.mechanics import FLAG_NONFINITE
from vnhc_gym.mechanics._kernels import psincos
from vnhc_gym.systems.currents import CURRENTS, RANDOM_PARAM_NAMES, RANDOM_WEIGHTS, get_current
from vnhc_gym.systems.usv import USV_PRESETS, make_usv

Array = NDArray[np.float64]
__all__ = ["DEFAULT_FORCE_BOUND", "USVStreamEnv", "USVTask", "USV_OBS_DIM", "VEL_SCALE", "RATE_SCALE"]

USV_OBS_DIM = 14
#: Default largest force (N): the geometric law with the baseline's gain k = 5 needs at most
#: ~57 N at the start of a nominal episode (500 seeds), so it never saturates.
DEFAULT_FORCE_BOUND = 100.0
VEL_SCALE = 2.0  #: m/s: velocities and currents are divided by this in the observation
RATE_SCALE = 2.0  #: rad/s: the turn rate is divided by this


@njit(cache=True)
def _observe_rows(start, stop, S, aux, domain, max_rate, clip, out, flags, status):
    for r in range(start, stop):
        if flags[r] & FLAG_NONFINITE:
            status[r] = STATUS_NONFINITE
        elif abs(S[r, 0]) > domain or abs(S[r, 1]) > domain:
            status[r] = STATUS_INVALID
        elif abs(S[r, 5]) > max_rate:
            status[r] = STATUS_SPIN
        else:
            status[r] = STATUS_OK
        th = S[r, 2]
        s, c = psincos(th)
        xd = S[r, 3]
        yd = S[r, 4]
        c1 = aux[r, 0]
        c2 = aux[r, 1]
        out[r, 0] = c
        out[r, 1] = s
        out[r, 2] = xd / VEL_SCALE
        out[r, 3] = yd / VEL_SCALE
        out[r, 4] = S[r, 5] / RATE_SCALE
        out[r, 5] = c1 / VEL_SCALE
        out[r, 6] = c2 / VEL_SCALE
        out[r, 7] = S[r, 0] / domain
        out[r, 8] = S[r, 1] / domain
        out[r, 9] = (s * xd - c * yd + c * c2 - s * c1) / VEL_SCALE  # phi w.r.t. the nominal current
        for j in range(4):
            out[r, 10 + j] = aux[r, 2 + j]  # nominal dC1/dx, dC1/dy, dC2/dx, dC2/dy (1/s)
        for j in range(out.shape[1]):
            out[r, j] = min(max(out[r, j], -clip), clip)


@njit(cache=True)
def _observe(S, aux, domain, max_rate, clip, out, flags, status):
    _observe_rows(0, S.shape[0], S, aux, domain, max_rate, clip, out, flags, status)


@njit(cache=True)
def _observe_at(rows, S, aux, domain, max_rate, clip, out, flags, status):
    for i in range(rows.shape[0]):
        _observe_rows(rows[i], rows[i] + 1, S, aux, domain, max_rate, clip, out, flags, status)


@njit(cache=True)
def _tail_rows(start, stop, oargs, fargs):
    """Observe and finish rows ``start:stop`` (see ConstraintTask.tail)."""
    S, aux, domain, max_rate, clip, out, flags, status = oargs
    _observe_rows(start, stop, S, aux, domain, max_rate, clip, out, flags, status)
    finish_rows(start, stop, *fargs)


@njit(cache=True)
def _tail(oargs, fargs):
    _tail_rows(0, oargs[0].shape[0], oargs, fargs)



@njit(cache=True)
def _sample_params(rows, rng, nominal, amp_idx, amp_w, mismatch_mask, delta, preset_state, use_preset, S, PT, PN):
    """First half of a new episode for ``rows``: nominal parameters (random current amplitudes),
    true parameters (mismatch) and the start pose (preset state if ``use_preset``)."""
    for i in range(rows.shape[0]):
        r = rows[i]
        for j in range(nominal.shape[0]):
            PN[r, j] = nominal[j]
        for k in range(0, amp_idx.shape[0], 2):
            z0, z1 = normal_pair(rng, r)
            PN[r, amp_idx[k]] = amp_w[k] * z0
            if k + 1 < amp_idx.shape[0]:
                PN[r, amp_idx[k + 1]] = amp_w[k + 1] * z1
        draw_mismatch(rng, r, PN[r], mismatch_mask, delta, PT[r])
        if use_preset:
            for j in range(6):
                S[r, j] = preset_state[j]
        else:
            S[r, 0] = uniform_ab(rng, r, -5.0, 5.0)
            S[r, 1] = uniform_ab(rng, r, -5.0, 5.0)
            S[r, 2] = uniform_ab(rng, r, -math.pi, math.pi)
            S[r, 3] = 0.0
            S[r, 4] = 0.0
            S[r, 5] = 0.0


@njit(cache=True)
def _sample_velocity(rows, rng, current, S):
    """Second half: the start velocity, from the true current ``current[r] = (C1, C2, ...)`` at
    the start position of row ``r`` in ``rows``."""
    for i in range(rows.shape[0]):
        r = rows[i]
        th = S[r, 2]
        s, c = psincos(th)
        c1 = current[r, 0]
        c2 = current[r, 1]
        # Forward through the water, and at least 0.3 m/s forward over ground along the heading:
        # on the manifold I thetadd = -m thetad v_forward, unstable when the boat goes backwards.
        forward = max(uniform_ab(rng, r, 0.5, 1.5), 0.3 - (c1 * c + c2 * s))
        phi0 = uniform_ab(rng, r, 0.2, 1.0) * sign(rng, r)  # off the manifold by construction
        # Velocity = current + forward speed along the heading + phi0 across it (mu = (sin, -cos)).
        S[r, 3] = c1 + forward * c + phi0 * s
        S[r, 4] = c2 + forward * s - phi0 * c
        S[r, 5] = uniform_ab(rng, r, -0.5, 0.5)


#: Stages of :func:`_draw_rows` (see :class:`~vnhc_gym.envs.task.ObserveKernels`): the start
#: velocity (stage 1) depends on the true current at the start position drawn in stage 0.
DRAW_STAGES = 2


@njit(cache=True)
def _draw_rows(rows, stage, dargs, outputs):
    """New episodes for ``rows``: stage 0 :func:`_sample_params`; stage 1 :func:`_sample_velocity`
    from ``outputs`` (the true model's outputs at the start pose), unless a preset fixed the state."""
    rng, nominal, amp_idx, amp_w, mismatch_mask, delta, preset_state, use_preset, S, PT, PN = dargs
    if stage == 0:
        _sample_params(rows, rng, nominal, amp_idx, amp_w, mismatch_mask, delta, preset_state, use_preset, S, PT, PN)
    elif not use_preset:
        _sample_velocity(rows, rng, outputs, S)


class USVTask(ConstraintTask):
    """Batched USV episodes (see :class:`USVStreamEnv` for the semantics)."""

    obs_dim = USV_OBS_DIM
    # Observations use self.aux: the *nominal* current map at the boat (what the controller is told).
    observe_kernels = ObserveKernels(_observe, _observe_at, _tail, __name__, _draw_rows, DRAW_STAGES)

    def __init__(self, config: TaskConfig, n: int, *, current: str = "random", current_params: dict | None = None,
                 mass: float = 10.0, inertia: float = 1.5, domain: float = 100.0, max_turn_rate: float = 10.0,
                 preset: str | None = None) -> None:
        if preset is not None:
            if preset not in USV_PRESETS:
                raise ValueError(f"unknown preset {preset!r}; valid names: {sorted(USV_PRESETS)}")
            pr = USV_PRESETS[preset]
            current, mass, inertia, current_params = pr.current, pr.m, pr.inertia, None
        field = get_current(current)
        for name, value in (("mass", mass), ("inertia", inertia), ("domain", domain),
                            ("max_turn_rate", max_turn_rate)):
            if not (_is_real(value) and np.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
        if current_params is not None:
            unknown = set(current_params) - set(field.defaults)
            if unknown:
                raise ValueError(f"current_params has unknown names {sorted(unknown)} for current {current!r}; "
                                 f"valid: {sorted(field.defaults)}")
        self.current = current
        self.field = field
        self.preset = preset
        self.domain = float(domain)
        self.max_turn_rate = float(max_turn_rate)
        self.fixed_field = current != "random" or current_params is not None
        model = make_usv(current)
        bound = config.force_bound if config.force_bound is not None else DEFAULT_FORCE_BOUND
        super().__init__(model, config, np.full(1, bound), n, default_impulse=0.3)
        names = model.param_names
        self._cidx = {k: names.index(f"c_{k}") for k in field.defaults}
        self.nominal = model.params(m=mass, I=inertia, **{f"c_{k}": v for k, v in (current_params or {}).items()})
        self.params_true[:] = self.nominal
        self.params_nominal[:] = self.nominal
        self._mismatch_mask = np.array([n_ in ("m", "I", "current_scale") for n_ in names])
        self._kick_mask = np.array([1.0, 1.0, 0.0])
        self._observe_args = (self.state, self.aux, self.domain, self.max_turn_rate, config.obs_clip, self.obs,
                              self.flags, self.status)
        # A random current draws its amplitudes c_<name> = RANDOM_WEIGHTS * N(0, 1) per episode.
        self._amp_idx = np.array([] if self.fixed_field else [names.index(f"c_{k}") for k in RANDOM_PARAM_NAMES],
                                 dtype=np.intp)
        self._amp_w = np.asarray([] if self.fixed_field else RANDOM_WEIGHTS, dtype=np.float64)
        self._preset_state = USV_PRESETS[preset].state() if preset is not None else np.zeros(6)
        self._draw_args = (self.rng, self.nominal, self._amp_idx, self._amp_w, self._mismatch_mask,
                           config.param_mismatch, self._preset_state, self.preset is not None, self.state,
                           self.params_true, self.params_nominal)

    def __getstate__(self) -> dict[str, Any]:
        state = super().__getstate__()
        state["field"] = None  # CurrentField holds lambdas; looked up again by name
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        super().__setstate__(state)
        self.field = get_current(self.current)

    def impulse_mask(self) -> NDArray[np.float64]:
        return self._kick_mask


    def current_params(self, i: int) -> dict[str, float]:
        """True current parameters of row ``i`` (times ``current_scale``) as a dict for CurrentField."""
        return {k: float(self.params_true[i, j]) for k, j in self._cidx.items()}


class USVStreamEnv(ConstraintEnv):
    r"""A boat in a sea current held to an affine velocity constraint (paper, Section IV-B).

    ## Description

    A USV with configuration ``q = (x, y, theta)``, mass ``m`` and inertia ``I`` moves in a
    current ``C(x, y)``. One control force ``u`` acts along ``sin(theta) dx - cos(theta) dy +
    d theta``; the current pushes the boat with ``W = m dV/dt``. The task is the virtual affine
    constraint

    $$\phi = \sin\theta\,\dot x - \cos\theta\,\dot y + \cos\theta\,C^2 - \sin\theta\,C^1 = 0,$$

    i.e. no sideways velocity relative to the water. The law derived from Theorem 2 (the
    paper's printed one is wrong, see NOTES.md) is
    $u^* = -m\,[k\phi + \dot\theta(\dot x\cos\theta + \dot y\sin\theta)]$.

    ## Action Space

    ``Box(-1, 1, (1,), float32)``: ``u = force_bound * clip(a, -1, 1)`` (N), held over ``dt``.

    ## Observation Space

    ``Box(-obs_clip, obs_clip, (14,), float32)``; ``C`` is the **nominal** current map at the
    boat (what a chart gives; it differs from the true current under ``mismatch``):

    | index | observation                      | index | observation                    |
    |-------|----------------------------------|-------|--------------------------------|
    | 0     | ``cos(theta)``                   | 7     | ``x / domain``                 |
    | 1     | ``sin(theta)``                   | 8     | ``y / domain``                 |
    | 2     | ``xd / 2`` (m/s)                 | 9     | ``phi / 2`` (with nominal C)   |
    | 3     | ``yd / 2``                       | 10    | ``dC1/dx`` (1/s)               |
    | 4     | ``thetad / 2`` (rad/s)           | 11    | ``dC1/dy``                     |
    | 5     | ``C1 / 2``                       | 12    | ``dC2/dx``                     |
    | 6     | ``C2 / 2``                       | 13    | ``dC2/dy``                     |

    The current's gradient gives a controller a local (affine) model of the current, which
    a sampled-data law that predicts over the control period needs.

    The law is computable from it: ``u* = -m [k 2 o9 + 2 o4 (2 o2 o0 + 2 o3 o1)]``.

    ## Rewards

    ``r = clip(-|phi| / phi_scale - action_cost * a^2, -reward_clip, 0)`` with the true
    ``phi`` (m/s) at the new state. ``info["abs_phi"]`` is ``|phi|``.

    ## Starting State

    Position ``U(-5, 5)^2`` m, heading ``U(-pi, pi)``, velocity = current + ``U(0.5, 1.5)`` m/s
    along the heading (raised if needed so that the ground speed along the heading is at least
    0.3 m/s) + ``±U(0.2, 1)`` m/s across it (so ``|phi(0)| >= 0.2``), turn rate
    ``U(-0.5, 0.5)`` rad/s. With ``current="random"`` a new field is drawn every episode.
    ``preset="paper-northeast"`` / ``"paper-anticyclone"`` reset to the paper's exact state.

    ## Episode End

    * Truncation: the time limit (``max_episode_steps=400`` with ``gym.make``, 20 s).
    * Termination: non-finite state (``"non_finite_state"``), the boat leaving the charted
      square ``|x|, |y| <= domain`` (``"out_of_domain"``) or spinning faster than
      ``max_turn_rate`` (``"turn_rate_exceeded"``), in ``info["termination_reason"]``. The
      constraint's internal dynamics are those of a knife edge: on the manifold
      ``I thetadd = -m thetad v``, with ``v`` the ground speed along the heading, which is
      unstable when the boat is pushed backwards (e.g. by a head current).

    ## Arguments

    | argument          | default   | meaning                                                     |
    |-------------------|-----------|-------------------------------------------------------------|
    | ``scenario``      | "nominal" | see Scenarios                                               |
    | ``preset``        | None      | ``"paper-northeast"``, ``"paper-anticyclone"``              |
    | ``current``       | "random"  | a name of ``vnhc_gym.systems.CURRENTS``                     |
    | ``current_params``| None      | overrides of the current's parameters (fixes a random field)|
    | ``mass``          | 10.0      | ``m`` (kg)                                                  |
    | ``inertia``       | 1.5       | ``I`` (kg m^2)                                              |
    | ``domain``        | 100.0     | half-width of the charted square (m)                        |
    | ``max_turn_rate`` | 10.0      | largest physical turn rate (rad/s)                          |
    | ``dt``            | 0.05      | control period (s)                                          |
    | ``substeps``      | 1         | RK4 steps per control period                                |
    | ``force_bound``   | 100.0     | largest force (N); see ``DEFAULT_FORCE_BOUND``              |
    | ``phi_scale``, ``action_cost``, ``reward_clip``, ``obs_clip`` | 1, 0, 100, 10 | as in FlockingAlign |
    | ``param_mismatch``| 0.0       | true ``m``, ``I``, current scale ``x (1 + U(-d, d))``       |
    | ``obs_noise``     | 0.0       | std of Gaussian observation noise                           |
    | ``impulse_prob``  | 0.0       | per-step probability of a random velocity kick             |
    | ``impulse_scale`` | 0.3       | std (m/s) of a kick on ``xd`` and ``yd``                    |
    | ``render_mode``   | None      | ``"rgb_array"`` or ``"human"``                              |

    ## Scenarios

    | scenario      | what changes                                                               |
    |---------------|----------------------------------------------------------------------------|
    | nominal       | nothing                                                                    |
    | saturated     | ``force_bound_scale=0.05``: 5 N, the law usually saturates at the start    |
    | mismatch      | ``param_mismatch=0.3``: true ``m``, ``I`` and current strength differ      |
    | noisy         | ``obs_noise=0.02``                                                         |
    | coarse        | ``dt=0.1, substeps=4``                                                     |
    | disturbance   | ``impulse_prob=0.05``: random 0.3 m/s velocity kicks                       |

    ## Info

    ``phi`` (float64 ``(1,)``), ``abs_phi``, ``state`` (``x, y, theta, xd, yd, thetad``),
    ``force`` (N), ``time``; plus ``termination_reason`` when terminated. The info of ``reset``
    also holds ``params`` (the episode's true ``m, I, current_scale, c_*``: constant over an
    episode, so not repeated at every step).

    ## Version History

    * v0: initial release.
    """

    task: USVTask


    def __init__(self, scenario: str = "nominal", preset: str | None = None, current: str = "random",
                 current_params: dict[str, float] | None = None, mass: float = 10.0, inertia: float = 1.5,
                 domain: float = 100.0, max_turn_rate: float = 10.0, render_mode: str | None = None,
                 **kwargs: Any) -> None:
        config, rest = resolve_config(TaskConfig, scenario, kwargs)
        reject_unknown(rest, ("scenario", "preset", "current", "current_params", "mass", "inertia", "domain",
                              "max_turn_rate", "render_mode"))
        self._check_render_mode(render_mode)
        if current not in CURRENTS:
            raise ValueError(f"unknown current {current!r}; valid names: {sorted(CURRENTS)}")
        self.scenario = scenario
        self.config = config
        self.task = USVTask(config, 1, current=current, current_params=current_params, mass=mass, inertia=inertia,
                            domain=domain, max_turn_rate=max_turn_rate, preset=preset)
        self.action_space = spaces.Box(-1.0, 1.0, (1,), np.float32)
        lim = np.float32(config.obs_clip)
        self.observation_space = spaces.Box(-lim, lim, (USV_OBS_DIM,), np.float32)
        self._bound = self.task.force_bound

    def render(self) -> NDArray[np.uint8] | None:
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; pass render_mode='rgb_array' or 'human'.")
            return None
        from vnhc_gym.envs.rendering import USVRenderer

        if self._renderer is None:
            self._renderer = USVRenderer(self.render_mode, self.metadata["render_fps"])
        task = self.task
        params = task.current_params(0)
        scale = float(task.params_true[0, task.model.param_names.index("current_scale")])

        def current(x: NDArray[np.float64], y: NDArray[np.float64]) -> NDArray[np.float64]:
            return scale * task.field.value(x, y, params)

        return self._renderer.draw(task.state[0], task.phi[0], current)
