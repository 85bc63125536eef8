"""What a step and a reset do to one episode, for every task: actions, impulses, reward, start.

An episode is row ``r`` of the arrays in [`Buffers`][vnhc_gym.envs.episode.Buffers]; the kernels here are called by
the generated step and reset kernels (`vnhc_gym.envs._step_template`) around the task's own
``draw`` and ``observe``.  The arrays and scalars travel as two named bundles,
[`Buffers`][vnhc_gym.envs.episode.Buffers] and [`StepConfig`][vnhc_gym.envs.episode.StepConfig], so
every argument can be followed by name from an environment's constructor to the kernel that reads
it.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np
from numba import njit

from vnhc_gym.mechanics import FEEDBACK_MODES
from vnhc_gym.rng import normal_pair, uniform

if TYPE_CHECKING:
    from vnhc_gym.tasks.base import Task

__all__ = ["Buffers", "StepConfig", "STATUS_OK", "STATUS_NONFINITE", "accept_actions", "finish_rows", "kick_row",
           "start_row", "step_config"]

STATUS_OK = 0
STATUS_NONFINITE = 1  #: the state (or phi) was not finite: the row kept its last finite state
# A task's termination code c >= 1 (what its ``observe`` returns) is stored as status 1 + c.

#: The reward shapes of ``EnvConfig.reward`` (`vnhc_gym.envs.config.REWARDS`) as the kernels read them.
RAW, BOUNDED, RECIPROCAL = 0, 1, 2
REWARD_SHAPES = {"raw": RAW, "bounded": BOUNDED, "reciprocal": RECIPROCAL}


class Buffers(NamedTuple):
    """The arrays of ``B`` episodes (row ``r`` is one episode); kernels write them in place.

    Shapes use ``n`` coordinates, ``m`` controls, ``n_params`` parameters, ``n_aux`` extra outputs
    and ``d`` observation entries.
    """

    state: np.ndarray  #: (B, 2n) the state (q, qd)
    next_state: np.ndarray  #: (B, 2n) where RK4 writes; keeps a non-finite result for the info
    params_true: np.ndarray  #: (B, n_params) the parameters that drive the dynamics
    params_nominal: np.ndarray  #: (B, n_params) the parameters a controller is told
    force: np.ndarray  #: (B, m) the held force of this step (N)
    force_applied: np.ndarray  #: (B, m) the applied force, averaged over the substeps
    action: np.ndarray  #: (B, m) the action, clipped to [-1, 1] (what the action cost charges)
    kick: np.ndarray  #: (B, n) this step's velocity impulse
    phi: np.ndarray  #: (B, m) phi at the state, with the true parameters
    phi_sf: np.ndarray  #: (B, m) the task's scale-free phi
    aux: np.ndarray  #: (B, n_aux) the extra outputs with the nominal parameters (for the observation)
    obs: np.ndarray  #: (B, d) float64 observation
    obs32: np.ndarray  #: (B, d) float32 observation (what the env returns)
    reward: np.ndarray  #: (B,)
    abs_phi: np.ndarray  #: (B,) mean_b |phi^b|
    abs_phi_sf: np.ndarray  #: (B,) mean_b |phi~^b|
    status: np.ndarray  #: (B,) int64: STATUS_OK, STATUS_NONFINITE or a task's code
    steps: np.ndarray  #: (B,) int64 steps since the episode's start
    flags: np.ndarray  #: (B,) int64 flags of the last RK4 step (FLAG_NONFINITE, FLAG_SINGULAR)
    rng: np.ndarray  #: (B,) uint64 each episode's random stream

    @classmethod
    def allocate(cls, n_rows: int, n: int, m: int, n_params: int, n_aux: int, obs_dim: int) -> Buffers:
        """Zeroed buffers for ``n_rows`` episodes."""
        def f(*shape: int) -> np.ndarray:
            return np.zeros(shape, dtype=np.float64)

        return cls(state=f(n_rows, 2 * n), next_state=f(n_rows, 2 * n), params_true=f(n_rows, n_params),
                   params_nominal=f(n_rows, n_params), force=f(n_rows, m), force_applied=f(n_rows, m),
                   action=f(n_rows, m), kick=f(n_rows, n), phi=f(n_rows, m), phi_sf=f(n_rows, m),
                   aux=f(n_rows, max(n_aux, 1)), obs=f(n_rows, obs_dim),
                   obs32=np.zeros((n_rows, obs_dim), dtype=np.float32), reward=f(n_rows), abs_phi=f(n_rows),
                   abs_phi_sf=f(n_rows), status=np.zeros(n_rows, dtype=np.int64),
                   steps=np.zeros(n_rows, dtype=np.int64), flags=np.zeros(n_rows, dtype=np.int64),
                   rng=np.zeros(n_rows, dtype=np.uint64))


class StepConfig(NamedTuple):
    """The scalars (and small constant arrays) of a step, the same for every row."""

    dt: float  #: control period (s)
    substeps: int  #: RK4 steps per control period
    bound: np.ndarray  #: (m,) force (N) of action 1 per control
    lo: np.ndarray  #: (m,) -bound: the in-loop law's total force is clipped to [lo, hi]
    hi: np.ndarray  #: (m,) bound
    mode: int  #: feedback mode of RK4: OPEN (the action only), CONTINUOUS or SAMPLED (in-loop law)
    gains: np.ndarray  #: (n_gains,) the in-loop law's gains
    singular_tol: float  #: singular test of the in-loop law
    reward_shape: int  #: RAW clip(-|phi| / phi_scale), BOUNDED exp(-|phi~| / sigma), RECIPROCAL 1/(1 + |phi~|/sigma)
    phi_scale: float
    reward_sigma: float
    action_cost: float
    reward_clip: float
    obs_noise: float  #: std of Gaussian observation noise
    obs_clip: float  #: observations are clipped to [-obs_clip, obs_clip]
    impulse_prob: float  #: probability per step of a velocity impulse
    impulse_scale: float  #: std of an impulse's velocity change
    impulse_mask: np.ndarray  #: (n,) weights of the velocity entries impulses kick (0 = never)
    nominal: np.ndarray  #: (n_params,) the task's nominal parameters (each episode starts from them)
    mismatch_mask: np.ndarray  #: (n_params,) bool: the parameters the mismatch perturbs (``Task.uncertain``)
    mismatch: float  #: relative half-width of the mismatch (``param_mismatch``)
    phi_sf_scale: float  #: the scale-free phi is phi / phi_sf_scale unless the task's ``observe`` says otherwise
    angles: np.ndarray  #: (k,) intp: the coordinates that are angles (kept in the inline sine's range)
    limit_index: np.ndarray  #: (L,) intp: state entries with a termination bound (``Task.limits``)
    limit_bound: np.ndarray  #: (L,) their bounds: the episode ends when ``|state[index]| > bound``
    limit_code: np.ndarray  #: (L,) int64: the termination code of each bound


def step_config(task: Task, feedback: str = "open", gains: Any = 1.0) -> StepConfig:
    """The step's named scalars, from the task's configuration and its declared defaults.

    Parameters
    ----------
    task : Task
        The configured task (its ``config``, force bounds, nominal parameters and declarations).
    feedback : {"open", "continuous", "sampled"}
        The in-loop law of `vnhc_gym.envs.runtime.Batch.set_feedback`.
    gains : float or array_like
        The in-loop law's gains (finite, >= 0), broadcast to the model's number of gains.
    """
    c = task.config
    model = task.model
    if feedback not in FEEDBACK_MODES:
        raise ValueError(f"feedback must be one of {sorted(FEEDBACK_MODES)}, got {feedback!r}")
    k = np.broadcast_to(np.asarray(gains, dtype=np.float64), (model.n_gains,)).copy()
    if not (np.all(np.isfinite(k)) and np.all(k >= 0)):
        raise ValueError(f"gains must be finite and >= 0, got {gains!r}")
    bound = task.force_bound
    names = model.param_names
    return StepConfig(
        dt=c.dt, substeps=c.substeps, bound=bound, lo=-bound, hi=bound.copy(), mode=FEEDBACK_MODES[feedback],
        gains=k, singular_tol=model.singular_tol, reward_shape=REWARD_SHAPES[c.reward], phi_scale=c.phi_scale,
        reward_sigma=task.reward_sigma if c.reward_sigma is None else c.reward_sigma,
        action_cost=c.action_cost, reward_clip=c.reward_clip, obs_noise=c.obs_noise, obs_clip=c.obs_clip,
        impulse_prob=c.impulse_prob,
        impulse_scale=task.default_impulse_scale if c.impulse_scale is None else c.impulse_scale,
        impulse_mask=np.asarray(task.impulse_mask, dtype=np.float64),
        nominal=np.asarray(task.nominal, dtype=np.float64),
        mismatch_mask=np.array([n in task.uncertain for n in names], dtype=np.bool_),
        mismatch=c.param_mismatch, phi_sf_scale=float(task.phi_sf_scale),
        angles=np.asarray(task.angles, dtype=np.intp),
        limit_index=np.array([i for _, i, _ in task.limits], dtype=np.intp),
        limit_bound=np.array([b for _, _, b in task.limits], dtype=np.float64),
        limit_code=np.array([task.reason_codes[r] for r, _, _ in task.limits], dtype=np.int64))


@njit(cache=True)
def accept_actions(rows: np.ndarray, actions: np.ndarray, bound: np.ndarray, force: np.ndarray,
                   action: np.ndarray) -> int:
    """For each row ``rows[i]``: ``action[r] = clip(actions[i], -1, 1)`` and ``force[r] = action[r] * bound``.

    Returns the index ``i`` of the first non-finite action (and writes nothing), or -1.
    """
    for i in range(rows.shape[0]):
        for j in range(actions.shape[1]):
            if not np.isfinite(actions[i, j]):
                return i
    for i in range(rows.shape[0]):
        r = rows[i]
        for j in range(actions.shape[1]):
            a = min(max(actions[i, j], -1.0), 1.0)
            action[r, j] = a
            force[r, j] = a * bound[j]
    return -1


@njit(cache=True, inline="always")
def kick_row(r: int, buf: Buffers, cfg: StepConfig) -> None:
    """This step's velocity impulse of row ``r``: with probability ``impulse_prob``,
    ``impulse_scale * N(0, 1)`` on each velocity entry, times ``impulse_mask``; else zero."""
    kick = buf.kick[r]
    n = kick.shape[0]
    for j in range(n):
        kick[j] = 0.0
    if not uniform(buf.rng, r) < cfg.impulse_prob:
        return
    for j in range(0, n, 2):
        z0, z1 = normal_pair(buf.rng, r)
        kick[j] = cfg.impulse_scale * z0 * cfg.impulse_mask[j]
        if j + 1 < n:
            kick[j + 1] = cfg.impulse_scale * z1 * cfg.impulse_mask[j + 1]


@njit(cache=True, inline="always")
def _add_noise(r: int, buf: Buffers, cfg: StepConfig) -> None:
    """``obs[r] = clip(obs[r] + N(0, obs_noise^2))`` entry-wise, from row ``r``'s stream."""
    obs = buf.obs[r]
    d = obs.shape[0]
    sigma = cfg.obs_noise
    clip = cfg.obs_clip
    for j in range(0, d, 2):
        z0, z1 = normal_pair(buf.rng, r)
        obs[j] = min(max(obs[j] + sigma * z0, -clip), clip)
        if j + 1 < d:
            obs[j + 1] = min(max(obs[j + 1] + sigma * z1, -clip), clip)


@njit(cache=True, inline="always")
def _mean_abs(x: np.ndarray) -> float:
    acc = 0.0
    for b in range(x.shape[0]):
        acc += abs(x[b])
    return acc / x.shape[0]


@njit(cache=True)
def finish_rows(rows: np.ndarray, buf: Buffers, cfg: StepConfig) -> None:
    """After the physics and the task's ``observe`` of every row in ``rows``: step count, observation
    noise, ``|phi|``, reward, and the float32 observation (kept at its last finite value, with
    ``STATUS_NONFINITE``, if the new one is not finite).

    A pass of its own over the rows rather than a per-row function inlined into the step loop: there,
    numba's reference counting of the bundle's arrays cost four times the bookkeeping itself.
    """
    for i in range(rows.shape[0]):
        r = rows[i]
        buf.steps[r] += 1
        if cfg.obs_noise > 0:
            _add_noise(r, buf, cfg)
        m = buf.phi.shape[1]
        acc = 0.0
        for b in range(m):
            acc += abs(buf.phi[r, b])
        buf.abs_phi[r] = acc / m
        if not abs(acc) < np.inf:  # phi overflowed (inf - inf) while the state stayed finite
            buf.status[r] = STATUS_NONFINITE
        buf.abs_phi_sf[r] = _mean_abs(buf.phi_sf[r])
        cost = 0.0
        for b in range(buf.action.shape[1]):
            cost += buf.action[r, b] * buf.action[r, b]
        cost = cfg.action_cost * cost / buf.action.shape[1]
        # An observation that is not finite (a state beyond what the task can observe) ends the
        # episode like a non-finite state; then, as for any non-finite state, the previous
        # observation stays.
        obs_finite = True
        for j in range(buf.obs.shape[1]):
            if not abs(buf.obs[r, j]) < np.inf:
                obs_finite = False
        if not obs_finite:
            buf.status[r] = STATUS_NONFINITE
        nonfinite = buf.status[r] == STATUS_NONFINITE
        if cfg.reward_shape != RAW:
            x = buf.abs_phi_sf[r] / cfg.reward_sigma
            rew = (math.exp(-x) if cfg.reward_shape == BOUNDED else 1.0 / (1.0 + x)) - cost
            if nonfinite or not rew == rew:
                rew = 0.0
            buf.reward[r] = min(max(rew, 0.0), 1.0)
        else:
            rew = -buf.abs_phi[r] / cfg.phi_scale - cost
            if nonfinite or not rew == rew:
                rew = -cfg.reward_clip
            buf.reward[r] = min(max(rew, -cfg.reward_clip), 0.0)
        if obs_finite and not nonfinite:
            for j in range(buf.obs.shape[1]):
                buf.obs32[r, j] = buf.obs[r, j]


@njit(cache=True, inline="always")
def start_row(r: int, buf: Buffers, cfg: StepConfig) -> None:
    """Bookkeeping of a new episode in row ``r``, after the task's ``observe``: status OK, zero
    step count and forces, ``|phi|``, observation noise and the float32 observation."""
    buf.status[r] = STATUS_OK
    buf.steps[r] = 0
    buf.flags[r] = 0
    for b in range(buf.force.shape[1]):
        buf.force[r, b] = 0.0
        buf.force_applied[r, b] = 0.0
        buf.action[r, b] = 0.0
    buf.abs_phi[r] = _mean_abs(buf.phi[r])
    buf.abs_phi_sf[r] = _mean_abs(buf.phi_sf[r])
    if cfg.obs_noise > 0:
        _add_noise(r, buf, cfg)
    for j in range(buf.obs.shape[1]):
        buf.obs32[r, j] = buf.obs[r, j]
