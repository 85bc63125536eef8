"""``vnhc_gym/SledCruise``: a knife-edge sled on ice held to no slip at a cruise speed."""

from __future__ import annotations

import math
from dataclasses import dataclass
from types import ModuleType
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from numpy.typing import NDArray

from vnhc_gym.envs.config import EnvConfig, TaskOptions, option
from vnhc_gym.envs.env import ConstraintEnv
from vnhc_gym.envs.rendering import Scene, hull_scene
from vnhc_gym.systems.sled import make_sled
from vnhc_gym.tasks.base import Task

Array = NDArray[np.float64]
__all__ = ["SledCruiseEnv", "SledCruiseTask", "SledOptions"]

OBS_VEL_SCALE = 2.0  #: m/s: velocities are divided by this in the observation
OBS_RATE_SCALE = 2.0  #: rad/s: the turn rate is divided by this
GRAVITY = 9.81  #: m/s^2: the blade's weight on the ice (friction)


class Args(NamedTuple):
    """The sled hooks' constants."""

    v_ref: float  #: the cruise speed (m/s)
    max_speed: float


def initial(key: jax.Array, p: jax.Array, args: Args) -> jax.Array:
    """Anywhere, any heading, off the constraint in both components (slipping, and faster or slower
    than the cruise speed), turning."""
    k_u, k_sign = jax.random.split(key)
    lo = jnp.array([-5.0, -5.0, -math.pi, 0.2, 0.1, -1.0])
    hi = jnp.array([5.0, 5.0, math.pi, 1.0, 0.5, 1.0])
    x, y, theta, dv, side, rate = jax.random.uniform(k_u, (6,), minval=lo, maxval=hi)
    sign_v, sign_side = jax.random.rademacher(k_sign, (2,), dtype=x.dtype)
    forward = args.v_ref + dv * sign_v
    side = side * sign_side
    c, s = jnp.cos(theta), jnp.sin(theta)
    return jnp.stack([x, y, theta, forward * c - side * s, forward * s + side * c, rate])


def observation(s: jax.Array, phi: jax.Array, p: jax.Array, args: Args) -> jax.Array:
    """Velocities in the sled's frame (forward, sideways), the turn rate and ``phi``."""
    c, sn = jnp.cos(s[2]), jnp.sin(s[2])
    return jnp.stack([(c * s[3] + sn * s[4]) / OBS_VEL_SCALE, (-sn * s[3] + c * s[4]) / OBS_VEL_SCALE,
                      s[5] / OBS_RATE_SCALE, phi[0] / OBS_VEL_SCALE, phi[1] / OBS_VEL_SCALE])


def terminations(s: jax.Array, phi: jax.Array, args: Args) -> dict[str, jax.Array]:
    """Faster than ``max_speed`` over ground (the turn-rate bound is one of the task's ``limits``)."""
    return {"speed_exceeded": jnp.hypot(s[3], s[4]) > args.max_speed}


def controller_inputs(obs: jax.Array, p: jax.Array, args: Args) -> tuple[jax.Array, jax.Array]:
    """The state in the frame that moves and turns with the sled (heading 0 at the origin: the law
    does not depend on where the sled is or where it heads) and the nominal parameters."""
    zero = jnp.zeros((), obs.dtype)
    return jnp.stack([zero, zero, zero, OBS_VEL_SCALE * obs[0], OBS_VEL_SCALE * obs[1], OBS_RATE_SCALE * obs[2]]), p


def recenter(s: jax.Array, p: jax.Array, args: Args) -> tuple[jax.Array, jax.Array]:
    """A state of the frame of `controller_inputs` one step on, in that frame anew (origin at the
    blade, heading 0): a filter's prediction, in the frame of the next observation."""
    c, sn = jnp.cos(s[2]), jnp.sin(s[2])
    zero = jnp.zeros((), s.dtype)
    return jnp.stack([zero, zero, zero, c * s[3] + sn * s[4], -sn * s[3] + c * s[4], s[5]]), p


def unmodelled(s: jax.Array, p: jax.Array, c: jax.Array, args: Args, *, system: ModuleType) -> jax.Array:
    """Coulomb friction of the blade on the ice, which the model's frictionless ice lacks: a force
    ``-c_0 m g sgn(v_f)`` against the forward speed, along the thrust's line, and a torque
    ``-c_1 sgn(thetad)`` against the turn (signs smoothed over 0.05 m/s and 0.05 rad/s)."""
    c_, sn = jnp.cos(s[2]), jnp.sin(s[2])
    forward = c_ * s[3] + sn * s[4]
    force = jnp.stack([-c[0] * p[0] * GRAVITY * jnp.tanh(forward / 0.05), -c[1] * jnp.tanh(s[5] / 0.05)])
    return jnp.sum(system.input_fields(s, p) * force, axis=-1)


@dataclass(frozen=True)
class SledOptions(TaskOptions):
    """The sled's own keyword arguments."""

    mass: float = option(20.0, "``m`` (kg)", low=0.0, low_open=True, high=1e9)
    inertia: float = option(2.0, "``I`` about the centre of mass (kg m^2)", low=0.0, low_open=True, high=1e9)
    offset: float = option(0.3, "``a``, centre of mass ahead of the blade (m)", low=1e-3, high=100.0)
    cruise_speed: float = option(1.5, "``v_ref`` (m/s)", low=0.0, high=100.0)
    max_speed: float = option(10.0, "termination speed (m/s)", low=0.0, low_open=True, high=1e6)
    max_turn_rate: float = option(10.0, "termination turn rate (rad/s)", low=0.0, low_open=True, high=1e6)


class SledCruiseTask(Task):
    """No slip at a cruise speed for a sled on ice (see [`SledCruiseEnv`][vnhc_gym.tasks.sled.SledCruiseEnv])."""

    name = "sled"
    Options = SledOptions
    reasons = ("speed_exceeded",)
    #: Thrust (N) and torque (N m) of action 1: the law with k = 5 needs at most 111 N and 31 N m at
    #: the start of a nominal episode (500 seeds).
    default_force_bound = (120.0, 40.0)
    force_units = ("N", "N m")
    default_impulse_scale = 0.3
    #: Width of the bounded reward (m/s).
    reward_sigma = 0.1
    phi_units = "m/s"
    phi_sf_scale = 1.0
    angles = (2,)
    uncertain = ("m", "I", "a")
    #: Coulomb friction: the blade's coefficient along the heading and the turning torque (N m).
    unmodelled_ranges = {"friction": (0.05, 0.3), "turn_friction_torque": (0.5, 4.0)}

    def __init__(self, config: EnvConfig, options: SledOptions) -> None:
        super().__init__(config, options)
        o = options
        self.max_speed = o.max_speed
        self.max_turn_rate = o.max_turn_rate
        self.model = make_sled()
        self.nominal = self.model.params(m=o.mass, I=o.inertia, a=o.offset, v_ref=o.cruise_speed)
        self.obs_dim = 5
        self.impulse_mask = np.array([1.0, 1.0, 0.0])
        self.args = Args(v_ref=o.cruise_speed, max_speed=o.max_speed)
        self.limits = (("turn_rate_exceeded", 5, o.max_turn_rate),)

    def scene(self, state: Array, phi: Array, params: Array) -> Scene:
        """The sled from above on the ice: its blade's heading, its velocity, both components of phi."""
        return hull_scene(state, phi, size=1.6)


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
    ``param_mismatch``, ``obs_noise``, ``impulse_prob``, ``obs_clip``, ``delay_min``, ``delay_max``,
    ``lag_min``, ``lag_max``, ``unmodelled`` and ``redraw`` are as for every task.
    | ``render_mode``   | None      | ``"rgb_array"`` or ``"human"``                 |

    ## Scenarios

    ``nominal``; ``saturated`` (bounds x 0.05); ``mismatch`` (true ``m``, ``I``, ``a`` x
    ``U(0.7, 1.3)``); ``noisy`` (observation noise 0.02); ``coarse`` (``dt = 0.1``, 4 substeps);
    ``disturbance`` (0.3 m/s velocity kicks with probability 0.05 per step).

    ``delay`` (2-6 steps), ``lag`` (0.1-0.5 s) and ``unmodelled``: the model wrong in structure,
    hidden from the controller and drawn again mid-episode, as for every task; ``unmodelled``:
    Coulomb friction of the blade, which the model's frictionless ice lacks: a force
    ``-mu m g sgn(v_f)`` along the heading, ``mu`` in ``U(0.05, 0.3)``, and a torque
    ``-c sgn(thetad)`` against the turn, ``c`` in ``U(0.5, 4)`` N m.

    ## Info

    ``phi`` (``(2,)``, m/s), ``abs_phi``, ``abs_phi_sf``, ``state`` (``x, y, theta, xd, yd,
    thetad``), ``force`` (N, N m), ``time``; ``params`` at reset (``m, I, a, v_ref``);
    ``termination_reason`` when terminated.
    Where the episode hides structure (``delay``, ``lag``, ``unmodelled``): ``delay_steps``,
    ``lag_time_constant`` (s) and ``unmodelled_coefficients``
    (``friction``, ``turn_friction_torque``), in force for the next step.

    ## Version History

    * v1: bounded reward; v0: the raw reward (as for every task).
    """

    task_class = SledCruiseTask
    task: SledCruiseTask
