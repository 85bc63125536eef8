"""``vnhc_gym/FlockingAlign-v0``: align three particles' velocities with a free-falling leader."""

from __future__ import annotations

import math
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from numba import njit
from numpy.typing import NDArray

from vnhc_gym.envs._random import sign, uniform_ab
from vnhc_gym.envs.base import ConstraintEnv
from vnhc_gym.envs.task import (
    STATUS_NONFINITE,
    STATUS_OK,
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
from vnhc_gym.systems.flocking import FLOCKING_PRESETS, make_flocking

Array = NDArray[np.float64]
__all__ = ["DEFAULT_FORCE_BOUND", "FlockingAlignEnv", "FlockingTask", "FlockingConfig", "LOG_SPEED_SCALE",
           "flocking_obs_dim"]

#: Default largest force (N): the geometric law with the baseline's gain k = 5 needs more than
#: this at the start of under 0.5 % of nominal episodes (max over 500 seeds: 264 N).
DEFAULT_FORCE_BOUND = 250.0
#: The leader's speed enters the observation as ``log(|v_N|) / LOG_SPEED_SCALE``.
LOG_SPEED_SCALE = 5.0


def flocking_obs_dim(n_agents: int) -> int:
    """Observation length: 2 per follower (velocity), 3 for the leader, 1 per follower (phi)."""
    return 3 * (n_agents - 1) + 3


@njit(cache=True)
def _observe_rows(start, stop, S, n_agents, clip, out, flags, status):
    nf = n_agents - 1
    vx0 = 2 * n_agents
    vz0 = 3 * n_agents
    for r in range(start, stop):
        status[r] = STATUS_NONFINITE if flags[r] & FLAG_NONFINITE else STATUS_OK
        lx = S[r, vx0 + nf]
        lz = S[r, vz0 + nf]
        speed = max(math.sqrt(lx * lx + lz * lz), 1e-12)
        inv = 1.0 / speed
        ex = lx * inv
        ez = lz * inv
        # Clipped as written (a second pass over the row to clip cost about 15 % of this loop).
        for b in range(nf):
            rx = S[r, vx0 + b] * inv
            rz = S[r, vz0 + b] * inv
            out[r, 2 * b] = min(max(rx, -clip), clip)
            out[r, 2 * b + 1] = min(max(rz, -clip), clip)
            out[r, 2 * nf + 3 + b] = min(max(ex * rz - rx * ez, -clip), clip)  # phi_b / |v_N|^2
        out[r, 2 * nf] = min(max(ex, -clip), clip)
        out[r, 2 * nf + 1] = min(max(ez, -clip), clip)
        out[r, 2 * nf + 2] = min(max(math.log(speed) / LOG_SPEED_SCALE, -clip), clip)


@njit(cache=True)
def _observe(S, n_agents, clip, out, flags, status):
    _observe_rows(0, S.shape[0], S, n_agents, clip, out, flags, status)


@njit(cache=True)
def _observe_at(rows, S, n_agents, clip, out, flags, status):
    for i in range(rows.shape[0]):
        _observe_rows(rows[i], rows[i] + 1, S, n_agents, clip, out, flags, status)


@njit(cache=True)
def _tail_rows(start, stop, oargs, fargs):
    """Observe and finish rows ``start:stop`` (see ConstraintTask.tail)."""
    S, n_agents, clip, out, flags, status = oargs
    _observe_rows(start, stop, S, n_agents, clip, out, flags, status)
    finish_rows(start, stop, *fargs)


@njit(cache=True)
def _tail(oargs, fargs):
    _tail_rows(0, oargs[0].shape[0], oargs, fargs)



@njit(cache=True)
def _sample(rows, rng, preset_state, use_preset, n_agents, nominal, mismatch_mask, delta, S, PT, PN):
    """New episodes for ``rows`` (state layout ``(x_1..x_N, z_1..z_N, xd_1..xd_N, zd_1..zd_N)``,
    leader last), drawn from each row's stream in a fixed order."""
    n = n_agents
    for i in range(rows.shape[0]):
        r = rows[i]
        if use_preset:
            for j in range(4 * n):
                S[r, j] = preset_state[j]
        else:
            # Leader: xd_N - zd_N in [1, 3] keeps C = diag((xd_N - zd_N)/m) away from singular for
            # the whole episode (zd_N only decreases in free fall).
            lx = uniform_ab(rng, r, 0.5, 2.0) * sign(rng, r)
            lz = lx - uniform_ab(rng, r, 1.0, 3.0)
            speed = math.hypot(lx, lz)
            angle = math.atan2(lz, lx)
            S[r, n - 1] = 0.0
            S[r, 2 * n - 1] = 100.0
            S[r, 3 * n - 1] = lx
            S[r, 4 * n - 1] = lz
            for b in range(n - 1):
                # Followers: off the manifold by construction (angle offset 0.3..1.2 rad either way).
                off = uniform_ab(rng, r, 0.3, 1.2) * sign(rng, r)
                mag = speed * uniform_ab(rng, r, 0.5, 2.0)
                S[r, 2 * n + b] = mag * math.cos(angle + off)
                S[r, 3 * n + b] = mag * math.sin(angle + off)
                S[r, b] = uniform_ab(rng, r, -20.0, 20.0)
                S[r, n + b] = 100.0 + uniform_ab(rng, r, -20.0, 20.0)
        for j in range(nominal.shape[0]):
            PN[r, j] = nominal[j]
        draw_mismatch(rng, r, nominal, mismatch_mask, delta, PT[r])


#: Stages of :func:`_draw_rows` (see :class:`~vnhc_gym.envs.task.ObserveKernels`): one, the start
#: state needs no output of the model.
DRAW_STAGES = 1


@njit(cache=True)
def _draw_rows(rows, stage, dargs, outputs):
    """New episodes for ``rows`` (stage 0 only): :func:`_sample` on ``dargs``."""
    _sample(rows, *dargs)


class FlockingConfig(TaskConfig):
    """:class:`TaskConfig` with the flocking defaults (``force_bound`` 250 N, impulses 1 m/s)."""


class FlockingTask(ConstraintTask):
    """Batched flocking episodes (see :class:`FlockingAlignEnv` for the semantics)."""

    observe_kernels = ObserveKernels(_observe, _observe_at, _tail, __name__, _draw_rows, DRAW_STAGES)

    def __init__(self, config: TaskConfig, n: int, *, n_agents: int = 4, masses: Any = 2.0, g: float = 10.0,
                 preset: str | None = None) -> None:
        if preset is not None:
            if preset not in FLOCKING_PRESETS:
                raise ValueError(f"unknown preset {preset!r}; valid names: {sorted(FLOCKING_PRESETS)}")
            p = FLOCKING_PRESETS[preset]
            n_agents, masses, g = p.n_agents, p.masses, p.g
        if isinstance(n_agents, bool) or not isinstance(n_agents, int | np.integer) or n_agents < 2:
            raise ValueError(f"n_agents must be an integer >= 2, got {n_agents!r}")
        m_arr = np.broadcast_to(np.asarray(masses, dtype=np.float64), (n_agents,)) if np.ndim(masses) == 0 else \
            np.asarray(masses, dtype=np.float64)
        if m_arr.shape != (n_agents,) or not np.all(np.isfinite(m_arr)) or np.any(m_arr <= 0):
            raise ValueError(f"masses must be a positive number or {n_agents} positive numbers, got {masses!r}")
        if not (_is_real(g) and np.isfinite(g) and g > 0):
            raise ValueError(f"g must be a finite number > 0, got {g!r}")
        self.n_agents = int(n_agents)
        self.preset = preset
        self.obs_dim = flocking_obs_dim(self.n_agents)  # set before the base allocates buffers
        model = make_flocking(self.n_agents)
        bound = config.force_bound if config.force_bound is not None else DEFAULT_FORCE_BOUND
        super().__init__(model, config, np.full(model.m, bound), n, default_impulse=1.0)
        self.nominal = np.array([*m_arr, g], dtype=np.float64)
        self.params_true[:] = self.nominal
        self.params_nominal[:] = self.nominal
        self._mismatch_mask = np.array([True] * (self.n_agents - 1) + [False, False])  # follower masses only
        self._kick_mask = np.zeros(2 * self.n_agents)
        self._kick_mask[: self.n_agents - 1] = 1.0  # follower xd
        self._kick_mask[self.n_agents: 2 * self.n_agents - 1] = 1.0  # follower zd
        self._observe_args = (self.state, self.n_agents, config.obs_clip, self.obs, self.flags, self.status)
        self._preset_state = FLOCKING_PRESETS[preset].state() if preset is not None else np.zeros(4 * self.n_agents)
        self._draw_args = (self.rng, self._preset_state, self.preset is not None, self.n_agents, self.nominal,
                           self._mismatch_mask, config.param_mismatch, self.state, self.params_true,
                           self.params_nominal)

    def impulse_mask(self) -> NDArray[np.float64]:
        return self._kick_mask


class FlockingAlignEnv(ConstraintEnv):
    r"""Three particles align their velocities with a free-falling leader (paper, Section IV-A).

    ## Description

    ``n_agents`` point masses move in the vertical xz-plane under gravity. The last one, the
    *leader*, falls freely; each *follower* ``b`` is pushed by one force ``u_b`` acting equally
    along x and z. The task is the virtual nonholonomic constraint

    $$\phi^b = \dot x_N \dot z_b - \dot x_b \dot z_N = 0,$$

    i.e. each follower's velocity parallel (or anti-parallel) to the leader's. The geometric
    controller of the paper (Theorem 2) is
    $u^*_b = m_b\,[g(\dot x_N - \dot x_b) - k_b\phi^b] / (\dot x_N - \dot z_N)$, which gives
    $\phi(t) = e^{-kt}\phi(0)$ under continuous feedback; see ``vnhc_gym.baselines``.
    Because everyone free-falls, raw velocities grow without bound; the observation is
    therefore expressed in units of the leader's speed.

    ## Action Space

    ``Box(-1, 1, (n_agents - 1,), float32)``: ``u_b = force_bound * clip(a_b, -1, 1)`` (N),
    held constant over the control period ``dt``.

    ## Observation Space

    ``Box(-obs_clip, obs_clip, (3 (n_agents - 1) + 3,), float32)``; with ``s = |v_N|``,
    ``e = v_N / s`` and ``r_b = v_b / s`` (default ``n_agents = 4``):

    | index        | observation                          | range (typical) |
    |--------------|--------------------------------------|-----------------|
    | 2b, 2b+1     | follower b velocity ``r_b = v_b / s`` | [-3, 3]        |
    | 2(N-1), +1   | leader direction ``e = v_N / s``     | [-1, 1]         |
    | 2(N-1)+2     | ``log(s) / 5``                       | [-0.3, 1.2]     |
    | 2(N-1)+3+b   | ``phi^b / s^2 = e_x r_bz - r_bx e_z`` | [-3, 3]        |

    Everything the law needs is there: ``s = exp(5 o[2(N-1)+2])`` and
    ``u*_b = m_b [g (e_x - r_bx) - k_b s phi^b/s^2] / (e_x - e_z)``. Positions do not enter the
    dynamics or the constraint and are not observed (they are in ``info["state"]``).

    ## Rewards

    ``r = clip(-mean_b |phi^b| / phi_scale - action_cost * mean(a^2), -reward_clip, 0)`` at the
    new state, with ``phi`` in raw units (m^2/s^2). ``info["abs_phi"]`` is ``mean_b |phi^b|``.

    ## Starting State

    Leader velocity ``xd_N = ±U(0.5, 2)``, ``zd_N = xd_N - U(1, 3)`` (so ``C`` stays invertible
    for the whole episode); follower ``b`` velocity at angle ``±U(0.3, 1.2)`` rad from the
    leader's and speed ``U(0.5, 2) |v_N|`` (off the manifold); positions within 20 m of the
    leader at (0, 100). ``preset="paper"`` instead resets to the paper's state every time.

    ## Episode End

    * Truncation: the time limit (``max_episode_steps=400`` when made with ``gym.make``, 20 s).
    * Termination: only if the state becomes non-finite (``info["termination_reason"] ==
      "non_finite_state"``); the last finite observation is returned with reward ``-reward_clip``.

    ## Arguments

    | argument          | default   | meaning                                                    |
    |-------------------|-----------|------------------------------------------------------------|
    | ``scenario``      | "nominal" | see Scenarios                                              |
    | ``preset``        | None      | ``"paper"``: the paper's masses, g and initial state        |
    | ``n_agents``      | 4         | particles, leader last                                     |
    | ``masses``        | 2.0       | follower and leader masses (kg), scalar or per particle    |
    | ``g``             | 10.0      | gravity (m/s^2)                                            |
    | ``dt``            | 0.05      | control period (s)                                         |
    | ``substeps``      | 1         | RK4 steps per control period                               |
    | ``force_bound``   | 250.0     | largest force (N); see ``DEFAULT_FORCE_BOUND``             |
    | ``phi_scale``     | 1.0       | reward normalisation of ``|phi|``                          |
    | ``action_cost``   | 0.0       | reward weight of ``mean(a^2)``                             |
    | ``reward_clip``   | 100.0     | rewards clipped to ``[-reward_clip, 0]``                   |
    | ``param_mismatch``| 0.0       | true follower masses ``m (1 + U(-d, d))`` per episode      |
    | ``obs_noise``     | 0.0       | std of Gaussian observation noise                          |
    | ``impulse_prob``  | 0.0       | per-step probability of a random velocity kick            |
    | ``impulse_scale`` | 1.0       | std (m/s) of a kick on each follower velocity component    |
    | ``obs_clip``      | 10.0      | observation bound                                          |
    | ``render_mode``   | None      | ``"rgb_array"`` or ``"human"``                             |

    ## Scenarios

    | scenario      | what changes                                                              |
    |---------------|---------------------------------------------------------------------------|
    | nominal       | nothing                                                                   |
    | saturated     | ``force_bound_scale=0.05``: 12.5 N, the law usually saturates at the start |
    | mismatch      | ``param_mismatch=0.3``: true masses differ from the nominal ones          |
    | noisy         | ``obs_noise=0.02``                                                        |
    | coarse        | ``dt=0.1, substeps=4``                                                    |
    | disturbance   | ``impulse_prob=0.05``: random 1 m/s velocity kicks                        |

    Explicit keyword arguments override a scenario's values.

    ## Info

    ``phi`` (float64, ``(N-1,)``), ``abs_phi`` (float), ``state`` (float64 ``(x.., z.., xd.., zd..)``),
    ``force`` (applied force, N), ``time`` (s); plus ``termination_reason`` when terminated.
    The info of ``reset`` also holds ``params`` (the episode's true masses and g: constant over
    an episode, so not repeated at every step).

    ## Version History

    * v0: initial release.
    """

    task: FlockingTask


    def __init__(self, scenario: str = "nominal", preset: str | None = None, n_agents: int = 4,
                 masses: Any = 2.0, g: float = 10.0, render_mode: str | None = None, **kwargs: Any) -> None:
        config, rest = resolve_config(FlockingConfig, scenario, kwargs)
        reject_unknown(rest, ("scenario", "preset", "n_agents", "masses", "g", "render_mode"))
        self._check_render_mode(render_mode)
        self.scenario = scenario
        self.config = config
        self.task = FlockingTask(config, 1, n_agents=n_agents, masses=masses, g=g, preset=preset)
        self.n_agents = self.task.n_agents
        m = self.n_agents - 1
        self.action_space = spaces.Box(-1.0, 1.0, (m,), np.float32)
        lim = np.float32(config.obs_clip)
        self.observation_space = spaces.Box(-lim, lim, (self.task.obs_dim,), np.float32)
        self._bound = self.task.force_bound

    def render(self) -> NDArray[np.uint8] | None:
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; pass render_mode='rgb_array' or 'human'.")
            return None
        from vnhc_gym.envs.rendering import FlockingRenderer

        if self._renderer is None:
            self._renderer = FlockingRenderer(self.n_agents, self.render_mode, self.metadata["render_fps"])
        return self._renderer.draw(self.task.state[0], self.task.phi[0])

