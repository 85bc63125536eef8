"""Batched episode logic shared by the single environments and their vector versions.

A :class:`ConstraintTask` holds ``B`` independent episodes of one system as float64 arrays
and advances them all with one compiled RK4 call.  ``FlockingAlignEnv`` and ``USVStreamEnv``
use a task with ``B = 1``; the vector environments use the same task with ``B = num_envs``, so
both run the same dynamics, observation, reward and termination code (no CartPole-style
duplication).  Randomness comes from one SplitMix64 stream per row, drawn inside the compiled
kernels (:mod:`vnhc_gym.envs._random`), so a vector env reproduces ``N`` single envs seeded
alike, bit for bit, and resetting many rows costs one kernel call.
"""

from __future__ import annotations

import numbers
import os
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, fields, replace
from time import perf_counter
from typing import Any, ClassVar, NamedTuple

import numpy as np
from numba import njit
from numpy.typing import NDArray

from vnhc_gym.envs._random import entropy_states, normal_pair, seed_states, uniform
from vnhc_gym.mechanics import FEEDBACK_MODES, ConstrainedSystem

__all__ = ["TaskConfig", "ConstraintTask", "apply_action", "check_action", "draw_mismatch", "finish_rows",
           "ObserveKernels", "reject_unknown", "resolve_config", "SCENARIOS"]

Array = NDArray[np.float64]

#: Scenario name -> overrides of TaskConfig fields (documented in each env's docstring).
SCENARIOS: dict[str, dict[str, Any]] = {
    "nominal": {},
    "saturated": {"force_bound_scale": 0.05},
    "mismatch": {"param_mismatch": 0.3},
    "noisy": {"obs_noise": 0.02},
    "coarse": {"dt": 0.1, "substeps": 4},
    "disturbance": {"impulse_prob": 0.05},
}


def _is_real(value: object) -> bool:
    """A real number (numpy scalars included), not a bool."""
    return isinstance(value, numbers.Real) and not isinstance(value, bool | np.bool_)


@dataclass(frozen=True)
class TaskConfig:
    """Keyword arguments common to both environments (see the env docstrings).

    Attributes
    ----------
    dt : float
        Control period in seconds (the action is held over it).
    substeps : int
        RK4 steps per control period.
    force_bound : float or None
        Largest absolute force (``None``: the env's default).
    force_bound_scale : float
        Multiplies ``force_bound`` (the ``saturated`` scenario uses 0.05).
    phi_scale : float
        ``|phi|`` is divided by this in the reward.
    action_cost : float
        Weight ``c_u`` of ``mean(a^2)`` in the reward.
    reward_clip : float
        Rewards are clipped to ``[-reward_clip, 0]`` (a diverging episode cannot dominate a batch).
    param_mismatch : float
        Relative half-width ``delta``: each episode the true physical parameters are the
        nominal ones times ``U(1 - delta, 1 + delta)`` (independently per parameter).
    obs_noise : float
        Standard deviation of Gaussian noise added to every observation entry.
    impulse_prob : float
        Probability per step of a random velocity impulse.
    impulse_scale : float or None
        Standard deviation of an impulse's velocity change (``None``: the env's default).
    obs_clip : float
        Observations are clipped to ``[-obs_clip, obs_clip]`` (the observation space).
    """

    dt: float = 0.05
    substeps: int = 1
    force_bound: float | None = None
    force_bound_scale: float = 1.0
    phi_scale: float = 1.0
    action_cost: float = 0.0
    reward_clip: float = 100.0
    param_mismatch: float = 0.0
    obs_noise: float = 0.0
    impulse_prob: float = 0.0
    impulse_scale: float | None = None
    obs_clip: float = 10.0

    def validate(self) -> None:
        """Raise ``ValueError`` naming the first invalid argument."""
        def positive(name: str, value: float | None, allow_none: bool = False) -> None:
            if value is None:
                if allow_none:
                    return
                raise ValueError(f"{name} must be a finite number > 0, got None")
            if not (_is_real(value) and np.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a finite number > 0, got {value!r}")

        def nonneg(name: str, value: float) -> None:
            if not (_is_real(value) and np.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be a finite number >= 0, got {value!r}")

        positive("dt", self.dt)
        if not (isinstance(self.substeps, int | np.integer) and not isinstance(self.substeps, bool)
                and self.substeps >= 1):
            raise ValueError(f"substeps must be an integer >= 1, got {self.substeps!r}")
        positive("force_bound", self.force_bound, allow_none=True)
        positive("force_bound_scale", self.force_bound_scale)
        positive("phi_scale", self.phi_scale)
        nonneg("action_cost", self.action_cost)
        positive("reward_clip", self.reward_clip)
        nonneg("param_mismatch", self.param_mismatch)
        if self.param_mismatch >= 1:
            raise ValueError(f"param_mismatch must be < 1 (parameters stay positive), got {self.param_mismatch}")
        nonneg("obs_noise", self.obs_noise)
        nonneg("impulse_prob", self.impulse_prob)
        if self.impulse_prob > 1:
            raise ValueError(f"impulse_prob must be <= 1, got {self.impulse_prob}")
        positive("impulse_scale", self.impulse_scale, allow_none=True)
        positive("obs_clip", self.obs_clip)


def resolve_config(cls: type[TaskConfig], scenario: str,
                   kwargs: Mapping[str, Any]) -> tuple[TaskConfig, dict[str, Any]]:
    """Build a config from a scenario's overrides, then explicit keyword arguments.

    Returns the config and the keyword arguments that are not config fields (env-specific).
    """
    if scenario not in SCENARIOS:
        raise ValueError(f"unknown scenario {scenario!r}; valid names: {sorted(SCENARIOS)}")
    names = {f.name for f in fields(cls)}
    own = {k: v for k, v in kwargs.items() if k in names}
    rest = {k: v for k, v in kwargs.items() if k not in names}
    config = replace(cls(), **{**SCENARIOS[scenario], **own})
    config.validate()
    return config, rest


def reject_unknown(rest: Mapping[str, Any], env_names: tuple[str, ...]) -> None:
    """Raise ``ValueError`` listing the valid names if ``rest`` holds unknown keyword arguments."""
    if rest:
        valid = sorted([*env_names, *(f.name for f in fields(TaskConfig))])
        raise ValueError(f"unknown keyword argument(s) {sorted(rest)}; valid: {valid}")


@njit(cache=True)
def check_action(action: np.ndarray, out: np.ndarray, row: int, bound: np.ndarray) -> bool:
    """Copy ``clip(action, -1, 1) * bound`` into ``out[row]``; False (nothing written) if non-finite."""
    for i in range(action.shape[0]):
        if not np.isfinite(action[i]):
            return False
    for i in range(action.shape[0]):
        out[row, i] = min(max(action[i], -1.0), 1.0) * bound[i]
    return True


@njit(cache=True)
def apply_action(action: np.ndarray, force: np.ndarray, applied: np.ndarray, row: int, bound: np.ndarray) -> bool:
    """:func:`check_action` that also stores the applied action ``clip(action, -1, 1)`` in
    ``applied[row]`` (what the action cost charges), in one compiled call (``np.clip`` alone costs
    about half a batch-1 step); False (nothing written) if non-finite."""
    for i in range(action.shape[0]):
        if not np.isfinite(action[i]):
            return False
    for i in range(action.shape[0]):
        a = min(max(action[i], -1.0), 1.0)
        applied[row, i] = a
        force[row, i] = a * bound[i]
    return True


STATUS_OK = 0
STATUS_NONFINITE = 1  #: the integrated state was not finite (row kept its last finite state)
STATUS_INVALID = 2  #: the system left its physically valid region (env-specific)
STATUS_SPIN = 3  #: the turn rate exceeded its physical limit (USV)
REASONS = {STATUS_NONFINITE: "non_finite_state", STATUS_INVALID: "out_of_domain", STATUS_SPIN: "turn_rate_exceeded"}
#: Batches at least this large step on numba's thread pool (when it is faster, see
#: ConstraintTask._step_timed).
PARALLEL_MIN_ROWS = 256
#: Row blocks of the threaded kernels (one per core of the 2-core reference machine).
N_CHUNKS = 2
#: Position of ``NEXT`` (where RK4 writes) in ConstraintTask._advance_args (the system's ``advance``).
_NEXT = 10
#: Sets of info arrays kept for reuse by ConstraintTask.batch_info (see there).
_POOL_SIZE = 3
#: First and largest interval (steps) between timing probes of the kernel not in use.
_PROBE_MIN, _PROBE_MAX = 16, 1024


#: libgomp settings while numba's thread pool starts (see _start_thread_pool).
_OMP_ENV = {"OMP_WAIT_POLICY": "passive", "GOMP_SPINCOUNT": "10000"}


def _start_thread_pool() -> None:
    """Start numba's thread pool with a *bounded* OpenMP barrier spin (unless the user set
    ``OMP_WAIT_POLICY`` or ``GOMP_SPINCOUNT``).

    libgomp's default spin-waiting (about 300000 spins) stalls the batched kernel for whole
    scheduler slices (10-20 ms a step instead of < 1 ms) as soon as the machine has more busy
    threads than cores (other processes, torch's own pool).  A purely passive wait avoids that but
    costs a futex wake-up at every launch: 13 us for an empty parallel region here, against
    2 us while the worker still spins.  ``GOMP_SPINCOUNT=10000`` (it overrides the passive
    policy) spins for about 0.1-0.3 ms, which covers the Python work between two steps of a
    vector env, then sleeps.  With two busy processes on the two cores it stepped the USV at
    N = 1024 no slower than the passive wait (ad hoc: median 330 vs 337 us, p99 4.3 vs 5.4 ms;
    the default spin: p99 8 ms).  The variables are only set while the pool starts (libgomp
    reads them then), so nothing else in the process sees them.
    """
    try:
        from numba.np.ufunc import parallel
    except ImportError:  # pragma: no cover
        return
    if getattr(parallel, "_is_initialized", True) or any(k in os.environ for k in _OMP_ENV):
        return
    os.environ.update(_OMP_ENV)
    try:
        parallel._launch_threads()
    except Exception:  # pragma: no cover - the kernel launches the pool itself then
        pass
    finally:
        for k in _OMP_ENV:
            del os.environ[k]


@njit(cache=True)
def _fill_kicks(dv, rng, skip, prob, scale, mask):
    """Velocity impulses: with probability ``prob`` per row, ``scale * N(0, 1) * mask``."""
    n = dv.shape[1]
    for r in range(dv.shape[0]):
        for j in range(n):
            dv[r, j] = 0.0
        if skip[r] or not uniform(rng, r) < prob:
            continue
        for j in range(0, n, 2):
            z0, z1 = normal_pair(rng, r)
            dv[r, j] = scale * z0 * mask[j]
            if j + 1 < n:
                dv[r, j + 1] = scale * z1 * mask[j + 1]


@njit(cache=True, inline="always")
def draw_mismatch(rng, r, nominal, mask, delta, out):
    """``out = nominal``, times ``U(1 - delta, 1 + delta)`` where ``mask`` (one draw per masked
    entry, from row ``r``'s stream; none if ``delta == 0``)."""
    for j in range(nominal.shape[0]):
        out[j] = nominal[j]
        if delta > 0 and mask[j]:
            out[j] = nominal[j] * (1.0 + delta * (2.0 * uniform(rng, r) - 1.0))


@njit(cache=True)
def _add_noise(obs, rng, r, sigma, clip):
    """``obs[r] = clip(obs[r] + N(0, sigma^2))`` entry-wise, from row ``r``'s stream."""
    d = obs.shape[1]
    for j in range(0, d, 2):
        z0, z1 = normal_pair(rng, r)
        obs[r, j] = min(max(obs[r, j] + sigma * z0, -clip), clip)
        if j + 1 < d:
            obs[r, j + 1] = min(max(obs[r, j + 1] + sigma * z1, -clip), clip)


@njit(cache=True)
def finish_rows(start, stop, obs, rng, skip, sigma, clip, phi, action, status, phi_scale, action_cost, reward_clip,
                reward, abs_phi, steps, obs32, snap, dt, state, next_state, force, o_obs, o_phi, o_abs, o_state,
                o_force, o_time):
    """After ``observe`` of rows ``start:stop``: observation noise (not for ``skip``-ped rows,
    whose step is discarded), reward, step counter and the float32 copy of the observation.
    Called once per row block by each environment's fused observe-and-finish kernels (``_tail``,
    ``_fused``).  If ``snap`` (``SNAP_COPY`` or ``SNAP_STEPPED``, see :func:`snapshot_rows`), the rows'
    info copies follow in the same pass, while the rows are still in cache.  A loop over rows,
    not a per-row function: per-row calls, even inlined ones, made this pass about 6x slower."""
    m = phi.shape[1]
    for r in range(start, stop):
        steps[r] += 1
        if sigma > 0 and not skip[r]:
            _add_noise(obs, rng, r, sigma, clip)
        acc = 0.0
        for b in range(m):
            acc += abs(phi[r, b])
        abs_phi[r] = acc / m
        if not abs(acc) < np.inf:  # phi overflowed (inf - inf) while the state stayed finite
            status[r] = STATUS_NONFINITE
        cost = 0.0
        for b in range(action.shape[1]):
            cost += action[r, b] * action[r, b]
        rew = -abs_phi[r] / phi_scale - action_cost * cost / action.shape[1]
        if status[r] == STATUS_NONFINITE or not rew == rew:
            rew = -reward_clip
        reward[r] = min(max(rew, -reward_clip), 0.0)
        for j in range(obs.shape[1]):
            obs32[r, j] = obs[r, j]
    if snap:
        snapshot_rows(start, stop, snap, status, steps, phi, abs_phi, obs32, dt, state, next_state, force, o_obs, o_phi,
                      o_abs, o_state, o_force, o_time)


@njit(cache=True)
def _start_rows(rows, obs, rng, sigma, clip, phi, status, abs_phi, obs32, steps, force, force_applied, action, flags):
    """Per-row bookkeeping of a reset, after ``observe``: status OK, ``|phi|``, noise, obs32."""
    for i in range(rows.shape[0]):
        r = rows[i]
        status[r] = STATUS_OK
        steps[r] = 0
        flags[r] = 0
        for b in range(force.shape[1]):
            force[r, b] = 0.0
            force_applied[r, b] = 0.0
            action[r, b] = 0.0
        acc = 0.0
        for b in range(phi.shape[1]):
            acc += abs(phi[r, b])
        abs_phi[r] = acc / phi.shape[1]
        if sigma > 0:
            _add_noise(obs, rng, r, sigma, clip)
        for j in range(obs.shape[1]):
            obs32[r, j] = obs[r, j]


@njit(cache=True, inline="always")
def _copy_rows(src, dst, start, stop):
    """``dst[start:stop] = src[start:stop]`` for C-contiguous arrays, as one flat loop (which
    LLVM vectorises; a loop per row over a few entries does not)."""
    d = 1
    for k in range(1, src.ndim):
        d *= src.shape[k]
    s = src.reshape(-1)
    o = dst.reshape(-1)
    for i in range(start * d, stop * d):
        o[i] = s[i]


#: Modes of :func:`snapshot_rows`: no copies, copy every info array, or copy all but the state,
#: which the step itself wrote into the info buffer (``ConstraintTask.step(info=...)``).
SNAP_NONE, SNAP_COPY, SNAP_STEPPED = 0, 1, 2


@njit(cache=True)
def snapshot_rows(start, stop, mode, status, steps, phi, abs_phi, obs32, dt, state, next_state, force, o_obs, o_phi,
                  o_abs, o_state, o_force, o_time):
    """The copies of :meth:`ConstraintTask.batch_info` for rows ``start:stop`` into the ``o_*``
    buffers, and ``o_time = steps * dt``.

    ``SNAP_COPY``: ``o_state`` from ``state``, or from ``next_state`` where non-finite.
    ``SNAP_STEPPED``: the RK4 step wrote its result into ``o_state`` (its ``NEXT``), which is
    already the info's state (the accepted state, or the non-finite one); only the non-finite
    rows go on to ``next_state``, where :meth:`ConstraintTask.step` documents them.  One copy of
    the whole state less per step.
    """
    if mode == SNAP_COPY:
        _copy_rows(state, o_state, start, stop)
    _copy_rows(obs32, o_obs, start, stop)
    _copy_rows(phi, o_phi, start, stop)
    _copy_rows(force, o_force, start, stop)
    _copy_rows(abs_phi, o_abs, start, stop)
    for r in range(start, stop):
        o_time[r] = steps[r] * dt
        if status[r] == STATUS_NONFINITE:
            for j in range(state.shape[1]):
                if mode == SNAP_COPY:
                    o_state[r, j] = next_state[r, j]
                else:
                    next_state[r, j] = o_state[r, j]


@njit(cache=True)
def _snapshot_at(rows, status, steps, phi, abs_phi, obs32, sargs):
    """:func:`snapshot_rows` (``SNAP_COPY``) for the rows listed in ``rows``, row by row (a call
    of the block form per row cost about 0.3 us a row)."""
    dt, state, next_state, force, o_obs, o_phi, o_abs, o_state, o_force, o_time = sargs
    for i in range(rows.shape[0]):
        r = rows[i]
        src = next_state if status[r] == STATUS_NONFINITE else state
        for j in range(state.shape[1]):
            o_state[r, j] = src[r, j]
        for j in range(obs32.shape[1]):
            o_obs[r, j] = obs32[r, j]
        for j in range(phi.shape[1]):
            o_phi[r, j] = phi[r, j]
        for j in range(force.shape[1]):
            o_force[r, j] = force[r, j]
        o_abs[r] = abs_phi[r]
        o_time[r] = steps[r] * dt


class ObserveKernels(NamedTuple):
    """An environment's compiled kernels.

    The observation kernels run over ``(*observe_args)``: ``all(*a)`` every row, ``at(rows, *a)``
    the given rows, ``tail(a, finish_args)`` observe then :func:`finish_rows` every row in one
    pass.  (numba cannot cache a kernel that takes another kernel as an argument, so each
    environment module compiles its own.)  ``draw(rows, stage, draw_args, outputs)`` draws new
    episodes in ``draw_stages`` stages; before each stage after the first, ``outputs`` holds the
    system's extra outputs with the *true* parameters at the state drawn so far (the USV draws
    its start velocity from the current at its start position).  ``module`` names the module,
    which also defines ``_tail_rows(start, stop, a, finish_args)``, ``_observe_at`` (= ``at``),
    ``_draw_rows`` (= ``draw``) and ``DRAW_STAGES``: the pieces that
    :mod:`vnhc_gym.envs._fused` joins with the system's kernels.
    """

    all: Any
    at: Any
    tail: Any
    module: str
    draw: Any
    draw_stages: int


class ConstraintTask:
    """``B`` episodes of a constrained system, stepped together.

    Subclasses set ``obs_dim`` and ``observe_kernels`` (their module's compiled kernels: the
    observation, and the draw of new episodes that :meth:`sample_rows` runs), build
    ``_observe_args`` and ``_draw_args`` (the kernels' arguments) in ``__init__``, and implement
    :meth:`impulse_mask` (which velocity entries impulses kick).
    """

    obs_dim: int
    observe_kernels: ClassVar[ObserveKernels]
    _observe_args: tuple[Any, ...]
    _draw_args: tuple[Any, ...]

    def __init__(self, model: ConstrainedSystem, config: TaskConfig, force_bound: Array, n: int,
                 default_impulse: float) -> None:
        self.model = model
        self.config = config
        self.n = n
        self.k = model.kernels
        if n >= PARALLEL_MIN_ROWS:
            _start_thread_pool()
        self._fused, self._reset_fused = self._fused_kernels()
        self._extra = (N_CHUNKS,) if n >= PARALLEL_MIN_ROWS else ()
        # Big batches time the threaded and the serial step now and then and run the faster one
        # (they compute the same numbers): on a machine with more busy threads than cores the
        # threaded one can be many times slower.  See _step_timed.
        self._timed = n >= PARALLEL_MIN_ROWS
        self._kernel_s = [0.0, 0.0]  # running mean seconds of [serial, threaded]
        self._threaded = True
        self._calls = 0
        self._probe_every = _PROBE_MIN
        self._next_probe = _PROBE_MIN
        with np.errstate(over="ignore"):
            self.force_bound = np.ascontiguousarray(force_bound, dtype=np.float64) * config.force_bound_scale
        if not np.all(np.isfinite(self.force_bound)):
            raise ValueError("force_bound * force_bound_scale must be finite, got "
                             f"{config.force_bound} * {config.force_bound_scale}")
        m, dim, n_p = model.m, 2 * model.n, len(model.param_names)
        self.state = np.zeros((n, dim))
        self.next_state = np.zeros((n, dim))
        self.params_true = np.tile(model.default_params, (n, 1))
        self.params_nominal = np.tile(model.default_params, (n, 1))
        self.force = np.zeros((n, m))
        self.force_applied = np.zeros((n, m))
        self.action = np.zeros((n, m))
        self.phi = np.zeros((n, m))
        self.aux = np.zeros((n, len(model.output_names)))
        self.obs = np.zeros((n, self.obs_dim))
        self.obs32 = np.zeros((n, self.obs_dim), dtype=np.float32)
        self.reward = np.zeros(n)
        self.abs_phi = np.zeros(n)
        self.status = np.zeros(n, dtype=np.int64)
        self.flags = np.zeros(n, dtype=np.int64)
        self.steps = np.zeros(n, dtype=np.int64)
        # Velocity kicks of the impulse scenario; no rows when impulses are off (advance skips them).
        self.dv = np.zeros((n if config.impulse_prob > 0 else 0, model.n))
        self._gains = np.zeros((n, model.n_gains))
        self._lo = -self.force_bound
        self._hi = self.force_bound.copy()
        if self.params_true.shape[1] != n_p:
            raise ValueError(f"model.default_params has {self.params_true.shape[1]} entries, expected one per "
                             f"name in model.param_names ({n_p})")
        self.impulse_scale = config.impulse_scale if config.impulse_scale is not None else default_impulse
        #: Per-row SplitMix64 states (see vnhc_gym.envs._random); seeded by seed_rows.
        self.rng = np.zeros(n, dtype=np.uint64)
        self._seeded = np.zeros(n, dtype=np.bool_)
        self._all_seeded = False
        self._no_skip = np.zeros(n, dtype=np.bool_)
        # Every buffer above is only ever written in place, so the kernels' argument tuples are
        # built once (attribute look-ups cost as much as the physics at batch 1).
        cfg = config
        self._advance_args = (self.state, self.params_true, self.force, self._gains, 0, self._lo, self._hi, cfg.dt,
                              cfg.substeps, model.singular_tol, self.next_state, self.force_applied, self.flags,
                              self.dv, self.phi, self.params_nominal, self.aux, *self._extra)
        self._finish_tail = (cfg.obs_noise, cfg.obs_clip, self.phi, self.action, self.status, cfg.phi_scale,
                             cfg.action_cost, cfg.reward_clip, self.reward, self.abs_phi, self.steps, self.obs32)
        # Sources of the info copies (snapshot_rows); with snap=False the kernels never touch the
        # outputs, so the sources themselves stand in for them (same types, one compiled version).
        self._snap_src = (cfg.dt, self.state, self.next_state, self.force_applied)
        self._no_snap = (SNAP_NONE, *self._snap_src, self.obs32, self.phi, self.abs_phi, self.state, self.force_applied,
                         self.abs_phi)
        self._finish_args = (self.obs, self.rng, self._no_skip, *self._finish_tail, *self._no_snap)
        self._start_args = (self.obs, self.rng, cfg.obs_noise, cfg.obs_clip, self.phi, self.status, self.abs_phi,
                            self.obs32, self.steps, self.force, self.force_applied, self.action, self.flags)
        self.feedback = "open"
        self._kicks = config.impulse_prob > 0

    def __getstate__(self) -> dict[str, Any]:
        # Compiled kernels are module functions of a generated module: re-bound on unpickle.
        state = self.__dict__.copy()
        state["k"] = None
        state["_fused"] = state["_reset_fused"] = None
        state.pop("_pool", None)  # reusable info buffers: not part of the state
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self.k = self.model.kernels
        self._fused, self._reset_fused = self._fused_kernels()

    def _fused_kernels(self) -> tuple[Any, Any]:
        """The threaded advance-then-tail kernel (big batches) and the one-call reset (batches),
        from :mod:`vnhc_gym.envs._fused`; None where not used."""
        if self.n < 2:
            return None, None
        from vnhc_gym.envs._fused import fused_module

        module = fused_module(self.k, self.observe_kernels.module)
        return (module.step_parallel if self.n >= PARALLEL_MIN_ROWS else None), module.reset_rows

    def set_feedback(self, feedback: str = "open", gains: Any = 1.0) -> None:
        """Run the geometric law inside the integrator, on top of the held force.

        ``"continuous"`` re-evaluates ``u*`` (with the *nominal* parameters and the true state)
        at every RK4 stage, ``"sampled"`` once per control period; ``"open"`` (default) turns it
        off.  The total force is clipped to the force bound at every stage.
        """
        if feedback not in FEEDBACK_MODES:
            raise ValueError(f"feedback must be one of {sorted(FEEDBACK_MODES)}, got {feedback!r}")
        k = np.broadcast_to(np.asarray(gains, dtype=np.float64), (self.model.n_gains,))
        if not np.all(np.isfinite(k)) or np.any(k < 0):
            raise ValueError(f"gains must be finite and >= 0, got {gains!r}")
        self._gains[:] = k
        args = list(self._advance_args)
        args[4] = FEEDBACK_MODES[feedback]
        self._advance_args = tuple(args)
        self.feedback = feedback

    # ------------------------------------------------------------------ hooks
    def sample_rows(self, rows: NDArray[np.intp]) -> None:
        """Draw new episodes for ``rows`` from their streams (``self.rng``): write
        ``self.state[rows]``, ``self.params_true[rows]`` and ``self.params_nominal[rows]``, with
        the subclass's ``observe_kernels.draw`` on ``self._draw_args`` (``self.aux[rows]`` holds
        the true model's outputs between its stages: :meth:`reset_rows` refills it)."""
        k = self.observe_kernels
        for stage in range(k.draw_stages):
            if stage:
                self.k.aux_at(rows, self.state, self.params_true, self.aux)
            k.draw(rows, stage, self._draw_args, self.aux)

    def observe(self, rows: NDArray[np.intp] | None = None) -> None:
        """Fill ``self.obs`` (clipped float64) and ``self.status`` from ``self.flags`` for ``rows``
        (default all), with the subclass's ``observe_kernels`` on ``self._observe_args``."""
        k = self.observe_kernels
        if rows is None:
            k.all(*self._observe_args)
        else:
            k.at(rows, *self._observe_args)

    def tail(self, finish_args: tuple[Any, ...]) -> None:
        """:meth:`observe` then :func:`finish_rows` for every row, fused in one compiled loop
        (the serial step; the threaded one runs it per row block with the RK4, ``_step_timed``)."""
        self.observe_kernels.tail(self._observe_args, finish_args)

    def impulse_mask(self) -> Array:
        """``(n,)`` weights of the velocity entries that impulses kick (0 = never)."""
        raise NotImplementedError

    # ------------------------------------------------------------------ shared logic
    def seed_rows(self, rows: NDArray[np.intp], seeds: Sequence[int | None]) -> None:
        """Seed the streams of ``rows``: ``seeds[k]`` for ``rows[k]`` (a non-negative int), or
        ``None`` to keep the row's stream (fresh operating-system entropy if never seeded)."""
        rows = np.asarray(rows, dtype=np.intp)
        given = np.array([s is not None for s in seeds], dtype=np.bool_)
        if given.any():
            self.rng[rows[given]] = seed_states([s for s in seeds if s is not None])
        fresh = rows[~given & ~self._seeded[rows]]
        if fresh.size:
            self.rng[fresh] = entropy_states(fresh.size)
        self._seeded[rows] = True

    def reset_row(self, i: int) -> None:
        """Start a new episode in row ``i`` (see :meth:`reset_rows`)."""
        self.reset_rows(np.array([i], dtype=np.intp))

    def reset_rows(self, rows: NDArray[np.intp], info: tuple[np.ndarray, ...] | None = None) -> None:
        """Start new episodes in ``rows``, each drawn from its own stream, and refresh their outputs.

        Other rows keep their float32 observations (``obs32``) and statuses.  Rows never seeded
        get an entropy seed first.  ``info`` (buffers from :meth:`info_buffers`) receives the
        rows' info copies (as :meth:`snapshot`).  Batches (``n > 1``) do all of it in one
        compiled call (:mod:`vnhc_gym.envs._fused`); the steps below are the same kernels one by one.
        """
        rows = np.asarray(rows, dtype=np.intp)
        if rows.size == 0:
            return
        if not self._all_seeded:
            if not self._seeded[rows].all():
                self.seed_rows(rows, [None] * rows.size)
            self._all_seeded = bool(self._seeded.all())
        if self._reset_fused is not None:
            snap = self._no_snap if info is None else (SNAP_COPY, *self._snap_src, *info)
            self._reset_fused(rows, self._draw_args, self.state, self.params_true, self.params_nominal, self.phi,
                              self.aux, self.flags, self._observe_args, self._start_args, snap[0],
                              (self.status, self.steps, self.phi, self.abs_phi, self.obs32, snap[1:]))
            return
        self.sample_rows(rows)
        self.flags[rows] = 0
        self.k.phi_at(rows, self.state, self.params_true, self.phi)
        self.k.aux_at(rows, self.state, self.params_nominal, self.aux)
        self.observe(rows)
        _start_rows(rows, *self._start_args)
        if info is not None:
            self.snapshot(rows, info)

    def step(self, skip: NDArray[np.bool_] | None = None,
             info: tuple[np.ndarray, ...] | None = None) -> NDArray[np.int64]:
        """Advance every row one control period with the forces in ``self.force``.

        ``skip`` marks rows whose step will be discarded (a vector env's sub-envs that are reset
        right after, in ``NEXT_STEP`` mode): they draw no noise or impulses, so their streams
        stay where a single env's would be.  Returns the per-row status (``STATUS_OK``,
        ``STATUS_NONFINITE``, ``STATUS_INVALID``, ...).  Rows whose state became non-finite keep
        their last finite state and observation; the non-finite state is left in
        ``self.next_state``.  ``info`` (buffers from :meth:`info_buffers`) receives the info
        copies of every row (as :meth:`batch_info`) in the same pass.
        """
        sk = self._no_skip if skip is None else skip
        if self._kicks:
            _fill_kicks(self.dv, self.rng, sk, self.config.impulse_prob, self.impulse_scale, self.impulse_mask())
        fargs: tuple[Any, ...] = self._finish_args
        aargs = self._advance_args
        if skip is not None or info is not None:
            snap = self._no_snap if info is None else (SNAP_STEPPED, *self._snap_src, *info)
            fargs = (self.obs, self.rng, sk, *self._finish_tail, *snap)
        if info is not None:
            # RK4 writes the new state straight into the info's state buffer (its NEXT), which
            # advance then accepts into self.state: one copy of the state less (SNAP_STEPPED).
            aargs = (*aargs[:_NEXT], info[3], *aargs[_NEXT + 1:])
        if self._timed:
            self._step_timed(aargs[:-1], fargs)
        else:
            self.k.advance(*aargs)
            self.tail(fargs)
        return self.status

    def _step_timed(self, aargs: tuple[Any, ...], fargs: tuple[Any, ...]) -> None:
        """Advance and tail with the faster of the threaded (fused) and the serial kernels (big
        batches only).

        The current choice's running time is tracked; every ``_probe_every`` calls the other
        kernel runs once instead, and becomes the choice if it was faster.  A losing probe doubles
        the interval (up to ``_PROBE_MAX``), a winning one resets it, so a wrong choice costs
        little and is undone soon after the machine's load changes.
        """
        self._calls += 1
        probe = self._calls >= self._next_probe
        threaded = self._threaded != probe
        t0 = perf_counter()
        if threaded:
            self._fused(aargs, self._observe_args, fargs, N_CHUNKS)
        else:
            self.k.advance(*aargs)
            self.tail(fargs)
        elapsed = perf_counter() - t0
        mean = self._kernel_s
        if not probe:
            mean[threaded] = elapsed if mean[threaded] == 0.0 else 0.75 * mean[threaded] + 0.25 * elapsed
            return
        if elapsed < mean[not threaded]:
            self._threaded = threaded
            mean[threaded] = elapsed
            self._probe_every = _PROBE_MIN
        else:
            self._probe_every = min(2 * self._probe_every, _PROBE_MAX)
        self._next_probe = self._calls + self._probe_every

    def batch_info(self) -> tuple[NDArray[np.float32], dict[str, Any], int]:
        """All rows at once: a copy of ``obs32``, the arrays of a step's :meth:`info` stacked over
        rows (same keys, dtypes and values; keep the two in sync) without ``termination_reason``,
        and the number of rows with a non-OK status (those that carry a termination reason).

        The copies go into :meth:`info_buffers`.  :meth:`step` can fill such buffers in its own
        pass instead (``step(info=bufs)``, then :meth:`snapshot` of rows changed since, and
        :meth:`info_from`).
        """
        bufs = self.info_buffers()
        self.snapshot(None, bufs)
        return self.info_from(bufs)

    def snapshot(self, rows: NDArray[np.intp] | None, bufs: tuple[np.ndarray, ...]) -> None:
        """Fill ``bufs`` (from :meth:`info_buffers`) with the info copies of ``rows`` (default all)."""
        sargs = (*self._snap_src, *bufs)
        if rows is None:
            snapshot_rows(0, self.n, SNAP_COPY, self.status, self.steps, self.phi, self.abs_phi, self.obs32, *sargs)
        else:
            _snapshot_at(rows, self.status, self.steps, self.phi, self.abs_phi, self.obs32, sargs)

    def info_from(self, bufs: tuple[np.ndarray, ...]) -> tuple[NDArray[np.float32], dict[str, Any], int]:
        """:meth:`batch_info`'s result from filled ``bufs``."""
        o_obs, o_phi, o_abs, o_state, o_force, o_time = bufs
        return o_obs, {"phi": o_phi, "abs_phi": o_abs, "state": o_state, "force": o_force,
                       "time": o_time}, int(np.count_nonzero(self.status))

    def info_buffers(self) -> tuple[np.ndarray, ...]:
        """A set of output arrays for the info copies that nobody else references.

        They are fresh arrays unless an earlier call's arrays are referenced by nobody any more
        (checked with ``sys.getrefcount``), in which case those are refilled: the usual training
        loop drops each step's infos, and reusing their memory avoids page-faulting about 1 MB
        of new arrays per step at 4096 sub-envs.  An array (or a view of it) that the caller
        still holds is never written again.
        """
        pool: list[tuple[np.ndarray, ...]] = self.__dict__.setdefault("_pool", [])
        for bufs in pool:
            # References: the tuple, getrefcount's argument and the comprehension's variable.
            if all(sys.getrefcount(b) <= 3 for b in bufs):
                return bufs
        bufs = (np.empty_like(self.obs32), np.empty_like(self.phi), np.empty_like(self.abs_phi),
                np.empty_like(self.state), np.empty_like(self.force_applied), np.empty_like(self.abs_phi))
        pool.append(bufs)
        if len(pool) > _POOL_SIZE:
            del pool[0]  # held by the caller: theirs now, freed when they let go
        return bufs

    def info(self, i: int, reset: bool = False) -> dict[str, Any]:
        """The documented ``info`` of row ``i`` (fresh float64 copies); ``reset``: the info of a
        reset, which also holds the episode's true parameters ``params`` (constant over an
        episode, so not copied again at every step)."""
        info = {
            "phi": self.phi[i].copy(),
            "abs_phi": float(self.abs_phi[i]),
            "state": self.state[i].copy(),
            "force": self.force_applied[i].copy(),
            "time": int(self.steps[i]) * self.config.dt,
        }
        if reset:
            info["params"] = self.params_true[i].copy()
        status = int(self.status[i])
        if status:
            info["termination_reason"] = REASONS[status]
            if status == STATUS_NONFINITE:
                info["state"] = self.next_state[i].copy()
        return info
