"""``vnhc_gym/SpacecraftPoint``: a rigid spacecraft made to spin about its axis 3, held vertical."""

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
from vnhc_gym.envs.rendering import Link, Scene, axes_3d
from vnhc_gym.systems.spacecraft import make_spacecraft
from vnhc_gym.tasks.base import Task

Array = NDArray[np.float64]
__all__ = ["SpacecraftOptions", "SpacecraftPointEnv", "SpacecraftTask"]

OBS_RATE_SCALE = 2.0  #: rad/s: body rates and phi are divided by this in the observation


class Args(NamedTuple):
    """The spacecraft hooks' constants."""

    max_rate: float


def _rates(s: jax.Array) -> jax.Array:
    """``omega = E(q) qd`` for ZYX angles ``q = (psi, theta, varphi)``."""
    st, ct, sp, cp = jnp.sin(s[1]), jnp.cos(s[1]), jnp.sin(s[2]), jnp.cos(s[2])
    return jnp.stack([-st * s[3] + s[5], ct * sp * s[3] + cp * s[4], ct * cp * s[3] - sp * s[4]])


def initial(key: jax.Array, p: jax.Array, args: Args) -> jax.Array:
    """Any yaw, pitch and roll within 45 degrees (a tilt of axis 3 up to 60 degrees), and a body
    rate off the constraint by 0.2-1 rad/s in each component, either way."""
    k_angles, k_off, k_sign = jax.random.split(key, 3)
    quarter = 0.25 * math.pi
    psi, theta, varphi = jax.random.uniform(k_angles, (3,), minval=jnp.array([-math.pi, -quarter, -quarter]),
                                            maxval=jnp.array([math.pi, quarter, quarter]))
    off = jax.random.uniform(k_off, (3,), minval=0.2, maxval=1.0) * jax.random.rademacher(k_sign, (3,),
                                                                                          dtype=psi.dtype)
    st, ct, sp, cp = jnp.sin(theta), jnp.cos(theta), jnp.sin(varphi), jnp.cos(varphi)
    spin, lam = p[3], p[4]
    w1 = -lam * ct * sp + off[0]  # the constraint's omega_1 = -lam z2, then off it
    w2 = lam * -st + off[1]  # omega_2 = lam z1
    w3 = spin + off[2]
    # qd = E^-1 omega, in closed form (|theta| < pi/2 here).
    psid = (sp * w2 + cp * w3) / ct
    return jnp.stack([psi, theta, varphi, psid, cp * w2 - sp * w3, w1 + st * psid])


def observation(s: jax.Array, phi: jax.Array, p: jax.Array, args: Args) -> jax.Array:
    """The vertical in body axes, the body rates and ``phi``."""
    st, ct, sp, cp = jnp.sin(s[1]), jnp.cos(s[1]), jnp.sin(s[2]), jnp.cos(s[2])
    return jnp.concatenate([jnp.stack([-st, ct * sp, ct * cp]), _rates(s) / OBS_RATE_SCALE, phi / OBS_RATE_SCALE])


def terminations(s: jax.Array, phi: jax.Array, args: Args) -> dict[str, jax.Array]:
    """A body rate above ``max_rate`` (the pitch bound is one of the task's ``limits``)."""
    return {"rate_exceeded": jnp.linalg.norm(_rates(s)) > args.max_rate}


def controller_inputs(obs: jax.Array, p: jax.Array, args: Args) -> tuple[jax.Array, jax.Array]:
    """The state read back from the observation, at yaw 0 (a turn about the vertical changes neither
    the dynamics nor the law): ``theta = -asin(z1)``, ``varphi = atan2(z2, z3)``, ``qd = E^-1 omega``;
    and the nominal parameters."""
    th = -jnp.arcsin(jnp.clip(obs[0], -1.0, 1.0))
    ph = jnp.arctan2(obs[1], obs[2])
    w = OBS_RATE_SCALE * obs[3:6]
    st, ct, sp, cp = jnp.sin(th), jnp.cos(th), jnp.sin(ph), jnp.cos(ph)
    psid = (sp * w[1] + cp * w[2]) / ct
    return jnp.stack([jnp.zeros_like(th), th, ph, psid, cp * w[1] - sp * w[2], w[0] + st * psid]), p


def unmodelled(s: jax.Array, p: jax.Array, c: jax.Array, args: Args, *, system: ModuleType) -> jax.Array:
    """A rate-dependent torque the rigid-body model lacks: the gyroscopic torque ``-omega x h`` of a
    rotor spinning inside the body with momentum ``h = c`` (N m s, body axes), a wheel the model
    does not know of."""
    torque = -jnp.cross(_rates(s), c)
    return jnp.sum(system.input_fields(s, p) * torque, axis=-1)


@dataclass(frozen=True)
class SpacecraftOptions(TaskOptions):
    """The spacecraft's own keyword arguments."""

    inertia_1: float = option(1.0, "``J1`` (kg m^2)", low=0.0, low_open=True, high=1e9)
    inertia_2: float = option(1.5, "``J2`` (kg m^2)", low=0.0, low_open=True, high=1e9)
    inertia_3: float = option(2.0, "``J3``, the spin axis (kg m^2)", low=0.0, low_open=True, high=1e9)
    spin_rate: float = option(1.0, "``Omega`` (rad/s; either sign, or 0)", low=-100.0, high=100.0)
    pointing_rate: float = option(1.0, "``lam`` (1/s), how fast axis 3 rises", low=0.0, low_open=True, high=100.0)
    max_pitch: float = option(1.396, "termination pitch (rad), short of gimbal lock at pi/2", low=0.0,
                              low_open=True, high=1.5)
    max_rate: float = option(10.0, "termination body rate (rad/s)", low=0.0, low_open=True, high=1e6)


def _rotation(state: Array) -> Array:
    """``R = Rz(psi) Ry(theta) Rx(varphi)`` of one state."""
    (cz, sz), (cy, sy), (cx, sx) = ((math.cos(a), math.sin(a)) for a in state[:3])
    rz = np.array([[cz, -sz, 0.0], [sz, cz, 0.0], [0.0, 0.0, 1.0]])
    ry = np.array([[cy, 0.0, sy], [0.0, 1.0, 0.0], [-sy, 0.0, cy]])
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cx, -sx], [0.0, sx, cx]])
    return rz @ ry @ rx


class SpacecraftTask(Task):
    """A spacecraft held to ``omega = lam e3 x z + Omega e3`` (see `SpacecraftPointEnv`)."""

    name = "spacecraft"
    Options = SpacecraftOptions
    reasons = ("rate_exceeded",)
    #: Body torques (N m) of action 1: the law with k = 5 needs at most (7.6, 11.8, 10.5) N m at
    #: the start of a nominal episode (500 seeds).
    default_force_bound = (10.0, 15.0, 15.0)
    force_units = ("N m", "N m", "N m")
    default_impulse_scale = 0.3
    #: Width of the bounded reward (rad/s): the law averages 0.98 over an episode, a start 0.006.
    reward_sigma = 0.1
    phi_units = "rad/s"
    angles = (0, 1, 2)
    uncertain = ("J1", "J2", "J3")
    #: The rotor's momentum in body axes (N m s).
    unmodelled_ranges = {"rotor_momentum_1": (-2.0, 2.0), "rotor_momentum_2": (-2.0, 2.0),
                         "rotor_momentum_3": (-2.0, 2.0)}

    def __init__(self, config: EnvConfig, options: SpacecraftOptions) -> None:
        super().__init__(config, options)
        o = options
        self.model = make_spacecraft()
        self.nominal = self.model.params(J1=o.inertia_1, J2=o.inertia_2, J3=o.inertia_3, Omega=o.spin_rate,
                                         lam=o.pointing_rate)
        self.obs_dim = 9
        self.impulse_mask = np.ones(3)
        self.args = Args(max_rate=o.max_rate)
        self.limits = (("gimbal_lock", 1, o.max_pitch),)

    def recenter(self, states: Array, params: Array) -> tuple[Array, Array]:
        """The predicted states at yaw 0, the frame of `controller_inputs`."""
        s = states.copy()
        s[:, 0] = 0.0
        return s, params

    def scene(self, state: Array, phi: Array, params: Array) -> Scene:
        """The body's three axes (x red, y green, z blue) in an oblique view, beside the vertical."""
        vertical = Link((0.0, 0.0), (0.0, 1.6), color=(160, 160, 160), width=1)
        s = np.asarray(state, dtype=np.float64)
        axes = axes_3d(_rotation(s), length=1.2) if np.all(np.isfinite(s[:3])) else []
        return Scene(links=[vertical, *axes], phi=list(phi), phi_units=self.phi_units, center=(0.0, 0.3),
                     extent=4.0)


class SpacecraftPointEnv(ConstraintEnv):
    r"""A rigid spacecraft made to spin about its axis 3 while that axis swings up to the vertical.

    ## Description

    A rigid body with principal inertias ``J1, J2, J3`` (distinct: the free body has gyroscopic
    coupling and an unstable intermediate axis), its attitude in ZYX Euler angles ``(psi, theta,
    varphi)``, turned by three body torques. With ``z`` the inertial vertical in body axes and
    ``omega`` the body rate, the task is the three-component virtual constraint

    $$\phi = \omega - \lambda\, e_3 \times z - \Omega\, e_3 = 0 :$$

    spin about body axis 3 at ``Omega`` while the transverse rate turns axis 3 towards the
    vertical. The decoupling matrix is constant, ``C = J^-1``: what is hard is cancelling the
    gyroscopic torque ``omega x J omega`` and the kinematics of the vertical. On the constraint the
    tilt obeys ``tan(tilt / 2) ~ exp(-lam t)`` whatever the inertia, and the pitch never exceeds
    the starting tilt, so the law stays clear of the Euler angles' singularity at ``theta = ±pi/2``
    (the chart's, not the law's: the transversality measure is 1 at every attitude).

    ## Action Space

    ``Box(-1, 1, (3,), float32)``: body torques ``tau_i = bound_i * a_i`` with ``bound = (10, 15,
    15)`` N m (``force_bound``), held over ``dt``.

    ## Observation Space

    ``Box(-obs_clip, obs_clip, (9,), float32)``:

    | index | observation                                   |
    |-------|-----------------------------------------------|
    | 0-2   | ``z = R^T e_z`` (the vertical in body axes)   |
    | 3-5   | ``omega / 2`` (rad/s), body rates             |
    | 6-8   | ``phi / 2`` (rad/s)                           |

    The yaw is not observed: a turn about the vertical changes neither the dynamics nor the task.

    ## Rewards

    ``r = exp(-mean_b |phi^b| / (1 rad/s) / reward_sigma) - action_cost * mean(a^2)`` in ``[0, 1]``
    (``-v1``); ``-v0``: ``clip(-mean_b |phi^b| / phi_scale, -reward_clip, 0)``.

    ## Starting State

    Yaw ``U(-pi, pi)``, pitch and roll ``U(-pi/4, pi/4)`` (a tilt up to 60 degrees); body rate
    ``omega = Omega e3 + lam e3 x z + phi0`` with ``phi0_b = ±U(0.2, 1.0)`` rad/s.

    ## Episode End

    * Truncation: the time limit (400 steps of 0.05 s with ``gym.make``).
    * Termination: a non-finite state, ``|theta| > max_pitch`` (``"gimbal_lock"``: near the
      singularity of the angles) or ``|omega| > max_rate`` (``"rate_exceeded"``).

    ## Arguments

    | argument          | default   | meaning                                            |
    |-------------------|-----------|----------------------------------------------------|
    | ``scenario``      | "nominal" | see Scenarios                                      |
    | ``inertia_1``     | 1.0       | ``J1`` (kg m^2)                                    |
    | ``inertia_2``     | 1.5       | ``J2`` (kg m^2)                                    |
    | ``inertia_3``     | 2.0       | ``J3``, the spin axis (kg m^2)                     |
    | ``spin_rate``     | 1.0       | ``Omega`` (rad/s; either sign, or 0)               |
    | ``pointing_rate`` | 1.0       | ``lam`` (1/s), how fast axis 3 rises               |
    | ``max_pitch``     | 1.396     | termination pitch (rad), 80 degrees                |
    | ``max_rate``      | 10.0      | termination body rate (rad/s)                      |
    | ``force_bound``   | (10, 15, 15) N m | one number sets all three                   |
    | ``reward_sigma``  | 0.1       | width (rad/s) of the bounded reward                |
    | ``impulse_scale`` | 0.3       | std (rad/s) of a kick to each angle rate           |
    | ``render_mode``   | None      | ``"rgb_array"`` or ``"human"``                     |

    ``dt``, ``substeps``, ``reward``, ``phi_scale``, ``reward_clip``, ``action_cost``,
    ``param_mismatch``, ``obs_noise``, ``impulse_prob``, ``obs_clip``, ``delay_min``, ``delay_max``,
    ``lag_min``, ``lag_max``, ``unmodelled`` and ``redraw`` are as for every task.

    ## Scenarios

    ``nominal``; ``saturated`` (bounds x 0.05); ``mismatch`` (true ``J1, J2, J3`` x ``U(0.7,
    1.3)``); ``noisy`` (observation noise 0.02); ``coarse`` (``dt = 0.1``, 4 substeps);
    ``disturbance`` (0.3 rad/s kicks to the angle rates with probability 0.05 per step).

    ``delay`` (2-6 steps), ``lag`` (0.1-0.5 s) and ``unmodelled``: the model wrong in structure,
    hidden from the controller and drawn again mid-episode, as for every task; ``unmodelled``:
    the gyroscopic torque ``-omega x h`` of a rotor spinning inside the body with
    momentum ``h`` in ``U(-2, 2)^3`` N m s (body axes), a wheel the rigid-body model does not know.

    ## Info

    ``phi`` (``(3,)``, rad/s), ``abs_phi``, ``abs_phi_sf``, ``state`` (``psi, theta, varphi, psid,
    thetad, varphid``), ``force`` (N m), ``time``; ``params`` at reset (``J1, J2, J3, Omega,
    lam``); ``termination_reason`` when terminated.
    Where the episode hides structure (``delay``, ``lag``, ``unmodelled``): ``delay_steps``,
    ``lag_time_constant`` (s) and ``unmodelled_coefficients``
    (``rotor_momentum_1``, ``_2``, ``_3``), in force for the next step.

    ## Version History

    * v1: bounded reward; v0: the raw reward (as for every task).
    """

    task_class = SpacecraftTask
    task: SpacecraftTask
