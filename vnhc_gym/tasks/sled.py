"""``vnhc_gym/SledCruise``: a knife-edge sled on ice held to no slip at a cruise speed."""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np
from numba import njit
from numpy.typing import NDArray

from vnhc_gym.envs.config import check_number
from vnhc_gym.envs.env import ConstraintEnv
from vnhc_gym.envs.episode import STATUS_NONFINITE, STATUS_OK, TASK_STATUS, Buffers, StepConfig
from vnhc_gym.envs.vector import ConstraintVectorEnv
from vnhc_gym.kernels import draw_mismatch, psincos, sign, uniform_ab
from vnhc_gym.mechanics import FLAG_NONFINITE
from vnhc_gym.mechanics.kernels import SINCOS_MAX_ARG
from vnhc_gym.systems.sled import make_sled
from vnhc_gym.tasks.base import Task

Array = NDArray[np.float64]
__all__ = ["SledCruiseEnv", "SledCruiseTask", "SledCruiseVectorEnv"]

VEL_SCALE = 2.0  #: m/s: velocities are divided by this in the observation
RATE_SCALE = 2.0  #: rad/s: the turn rate is divided by this
STATUS_FAST = TASK_STATUS  #: faster than max_speed
STATUS_SPIN = TASK_STATUS + 1  #: turning faster than max_turn_rate


class Args(NamedTuple):
    """The sled hooks' constants."""

    nominal: np.ndarray  #: nominal parameters (m, I, a, v_ref)
    mismatch_mask: np.ndarray  #: m, I, a
    mismatch: float
    max_speed: float
    max_rate: float
    vel_scale: float  #: the scale of the scale-free phi (m/s)


DRAW_STAGES = 1


@njit(cache=True)
def draw(r: int, stage: int, buf: Buffers, cfg: StepConfig, args: Args) -> None:
    """A new episode: anywhere, any heading, off the constraint in both components (slipping, and
    faster or slower than the cruise speed), turning."""
    rng = buf.rng
    S = buf.state[r]
    for j in range(args.nominal.shape[0]):
        buf.params_nominal[r, j] = args.nominal[j]
    draw_mismatch(rng, r, args.nominal, args.mismatch_mask, args.mismatch, buf.params_true[r])
    S[0] = uniform_ab(rng, r, -5.0, 5.0)
    S[1] = uniform_ab(rng, r, -5.0, 5.0)
    S[2] = uniform_ab(rng, r, -math.pi, math.pi)
    forward = args.nominal[3] + uniform_ab(rng, r, 0.2, 1.0) * sign(rng, r)
    side = uniform_ab(rng, r, 0.1, 0.5) * sign(rng, r)
    s, c = psincos(S[2])
    S[3] = forward * c - side * s
    S[4] = forward * s + side * c
    S[5] = uniform_ab(rng, r, -1.0, 1.0)


@njit(cache=True, inline="always")
def observe(r: int, buf: Buffers, cfg: StepConfig, args: Args) -> None:
    """Velocities in the sled's frame (forward, sideways), the turn rate and ``phi``; the status; the
    scale-free ``phi / vel_scale``."""
    S = buf.state[r]
    out = buf.obs[r]
    s, c = psincos(S[2])
    forward = c * S[3] + s * S[4]
    side = -s * S[3] + c * S[4]
    if buf.flags[r] & FLAG_NONFINITE:
        buf.status[r] = STATUS_NONFINITE
    elif math.hypot(S[3], S[4]) > args.max_speed:
        buf.status[r] = STATUS_FAST
    elif abs(S[5]) > args.max_rate:
        buf.status[r] = STATUS_SPIN
    elif not abs(S[2]) <= SINCOS_MAX_ARG:  # a heading beyond the inline sine's range: the run blew up
        buf.status[r] = STATUS_NONFINITE
    else:
        buf.status[r] = STATUS_OK
    out[0] = forward / VEL_SCALE
    out[1] = side / VEL_SCALE
    out[2] = S[5] / RATE_SCALE
    out[3] = buf.phi[r, 0] / VEL_SCALE
    out[4] = buf.phi[r, 1] / VEL_SCALE
    clip = cfg.obs_clip
    for j in range(out.shape[0]):
        out[j] = min(max(out[j], -clip), clip)
    for b in range(2):
        buf.phi_sf[r, b] = buf.phi[r, b] / args.vel_scale


class SledCruiseTask(Task):
    """No slip at a cruise speed for a sled on ice (see :class:`SledCruiseEnv`)."""

    name = "sled"
    options = {"mass": 20.0, "inertia": 2.0, "offset": 0.3, "cruise_speed": 1.5, "max_speed": 10.0,
               "max_turn_rate": 10.0}
    reasons = ("speed_exceeded", "turn_rate_exceeded")
    #: Thrust (N) and torque (N m) of action 1: the law with k = 5 needs at most 111 N and 31 N m at
    #: the start of a nominal episode (500 seeds).
    default_force_bound = (120.0, 40.0)  # type: ignore[assignment]
    default_impulse_scale = 0.3
    #: Width of the bounded reward (m/s).
    reward_sigma = 0.1
    phi_units = "m/s"
    phi_sf_meaning = "the blade's sideways speed and the speed error, over 1 m/s"
    velocity_scale = 1.0
    angles = (2,)
    uncertain = ("m", "I", "a")

    def __init__(self, config: Any, *, mass: float = 20.0, inertia: float = 2.0, offset: float = 0.3,
                 cruise_speed: float = 1.5, max_speed: float = 10.0, max_turn_rate: float = 10.0) -> None:
        self.config = config
        m_ = check_number("mass", mass, low=0.0, low_open=True, high=1e9)
        i_ = check_number("inertia", inertia, low=0.0, low_open=True, high=1e9)
        a_ = check_number("offset", offset, low=1e-3, high=100.0)
        v_ = check_number("cruise_speed", cruise_speed, low=0.0, high=100.0)
        self.max_speed = check_number("max_speed", max_speed, low=0.0, low_open=True, high=1e6)
        self.max_turn_rate = check_number("max_turn_rate", max_turn_rate, low=0.0, low_open=True, high=1e6)
        self.model = make_sled()
        self.nominal = self.model.params(m=m_, I=i_, a=a_, v_ref=v_)
        self.obs_dim = 5
        self.impulse_mask = np.array([1.0, 1.0, 0.0])
        names = self.model.param_names
        self.args = Args(nominal=self.nominal, mismatch_mask=np.array([n in self.uncertain for n in names]),
                         mismatch=config.param_mismatch, max_speed=self.max_speed, max_rate=self.max_turn_rate,
                         vel_scale=self.velocity_scale)

    @property
    def force_bound(self) -> Array:
        c = self.config
        bound = np.asarray(self.default_force_bound if c.force_bound is None else (c.force_bound,) * 2, dtype=float)
        return bound * c.force_bound_scale

    def controller_inputs(self, obs: Array) -> tuple[Array, Array]:
        """States in the frame that moves and turns with the sled (heading 0 at the origin: the law
        does not depend on where the sled is or where it heads) and the nominal parameters."""
        o = np.asarray(obs, dtype=np.float64)
        zero = np.zeros(o.shape[0])
        st = np.stack([zero, zero, zero, VEL_SCALE * o[:, 0], VEL_SCALE * o[:, 1], RATE_SCALE * o[:, 2]], axis=1)
        return st, np.tile(self.nominal, (o.shape[0], 1))

    def recenter(self, states: Array, params: Array) -> tuple[Array, Array]:
        """The predicted states in the sled's new frame (origin at the blade, heading 0)."""
        s = states.copy()
        th = s[:, 2]
        c, sn = np.cos(th), np.sin(th)
        s[:, 3], s[:, 4] = c * states[:, 3] + sn * states[:, 4], -sn * states[:, 3] + c * states[:, 4]
        s[:, 0:3] = 0.0
        return s, params


class SledCruiseEnv(ConstraintEnv):
    r"""A knife-edge sled on ice held to no sideways slip at a cruise speed.

    ## Description

    A sled with a blade at ``q = (x, y)``, heading ``theta``, mass ``m``, inertia ``I`` about its
    centre of mass, which sits ``a`` ahead of the blade (so the mass matrix depends on the
    heading). It is steered by a thrust ``u_1`` along the blade and a torque ``u_2``. Nothing holds
    the blade on the ice: the task is the two-component virtual constraint

    $$\phi^1 = -\sin\theta\,\dot x + \cos\theta\,\dot y = 0,\qquad
      \phi^2 = \cos\theta\,\dot x + \sin\theta\,\dot y - v_{ref} = 0,$$

    no sideways slip, at the cruise speed. The decoupling matrix ``C = [[0, -a/I], [1/m, 0]]`` is
    not diagonal: the slip can only be corrected through the torque, by way of the offset mass, so
    thrust and torque must be coordinated. On the constraint the turn rate dies out
    (a Chaplygin sleigh with its mass ahead of the blade).

    ## Action Space

    ``Box(-1, 1, (2,), float32)``: thrust ``u_1 = 120 N * a_1`` and torque ``u_2 = 40 N m * a_2``
    (``force_bound``), held over ``dt``.

    ## Observation Space

    ``Box(-obs_clip, obs_clip, (5,), float32)``: in the sled's frame, with ``v_f``, ``v_s`` the
    velocity of the blade along and across the heading:

    | index | observation            |
    |-------|------------------------|
    | 0     | ``v_f / 2`` (m/s)      |
    | 1     | ``v_s / 2``            |
    | 2     | ``thetad / 2`` (rad/s) |
    | 3     | ``phi^1 / 2`` (= v_s/2) |
    | 4     | ``phi^2 / 2`` (= (v_f - v_ref)/2) |

    ## Rewards

    ``r = exp(-mean_b |phi^b| / (1 m/s) / reward_sigma) - action_cost * mean(a^2)`` in ``[0, 1]``
    (``-v1``); ``-v0``: ``clip(-mean_b |phi^b| / phi_scale, -reward_clip, 0)``.

    ## Starting State

    Blade position ``U(-5, 5)^2`` m, heading ``U(-pi, pi)``, forward speed ``v_ref ± U(0.2, 1)``,
    sideways slip ``±U(0.1, 0.5)`` m/s, turn rate ``U(-1, 1)`` rad/s.

    ## Episode End

    * Truncation: the time limit (400 steps of 0.05 s with ``gym.make``).
    * Termination: a non-finite state, a speed above ``max_speed`` (``"speed_exceeded"``) or a turn
      rate above ``max_turn_rate`` (``"turn_rate_exceeded"``).

    ## Arguments

    | argument          | default   | meaning                                        |
    |-------------------|-----------|------------------------------------------------|
    | ``scenario``      | "nominal" | see Scenarios                                  |
    | ``mass``          | 20.0      | ``m`` (kg)                                     |
    | ``inertia``       | 2.0       | ``I`` about the centre of mass (kg m^2)        |
    | ``offset``        | 0.3       | ``a``, centre of mass ahead of the blade (m)   |
    | ``cruise_speed``  | 1.5       | ``v_ref`` (m/s)                                |
    | ``max_speed``     | 10.0      | termination speed (m/s)                        |
    | ``max_turn_rate`` | 10.0      | termination turn rate (rad/s)                  |
    | ``force_bound``   | 120 N, 40 N m | one number sets both bounds                |
    | ``reward_sigma``  | 0.1       | width (m/s) of the bounded reward              |
    | ``impulse_scale`` | 0.3       | std (m/s) of a velocity kick                   |

    ``dt``, ``substeps``, ``reward``, ``phi_scale``, ``reward_clip``, ``action_cost``,
    ``param_mismatch``, ``obs_noise``, ``impulse_prob`` and ``obs_clip`` are as for every task.
    | ``render_mode``   | None      | ``"rgb_array"`` or ``"human"``                 |

    ## Scenarios

    ``nominal``; ``saturated`` (bounds x 0.05); ``mismatch`` (true ``m``, ``I``, ``a`` x
    ``U(0.7, 1.3)``); ``noisy`` (observation noise 0.02); ``coarse`` (``dt = 0.1``, 4 substeps);
    ``disturbance`` (0.3 m/s velocity kicks with probability 0.05 per step).

    ## Info

    ``phi`` (``(2,)``, m/s), ``abs_phi``, ``abs_phi_sf``, ``state`` (``x, y, theta, xd, yd,
    thetad``), ``force`` (N, N m), ``time``; ``params`` at reset (``m, I, a, v_ref``);
    ``termination_reason`` when terminated.

    ## Version History

    * v1: bounded reward; v0: the raw reward (as for every task).
    """

    task_class = SledCruiseTask
    task: SledCruiseTask

    def _draw(self, row: int) -> NDArray[np.uint8] | None:
        from vnhc_gym.envs.rendering import USVRenderer

        if self._renderer is None:
            self._renderer = USVRenderer(str(self.render_mode), self.metadata["render_fps"])
        buf = self.batch.buf
        return self._renderer.draw(buf.state[row], buf.phi[row], lambda x, y: np.zeros((*np.shape(x), 2)))


class SledCruiseVectorEnv(ConstraintVectorEnv):
    """The native vector version of :class:`SledCruiseEnv`."""

    env_class = SledCruiseEnv
