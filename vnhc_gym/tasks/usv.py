"""``vnhc_gym/USVStream``: hold a boat in a sea current to an affine velocity constraint."""

from __future__ import annotations

import math
from dataclasses import dataclass
from types import ModuleType
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from numpy.typing import NDArray

from vnhc_gym.envs.config import EnvConfig, TaskOptions, check_number, option
from vnhc_gym.envs.env import ConstraintEnv
from vnhc_gym.envs.rendering import Scene, hull_scene
from vnhc_gym.mechanics import ConstrainedSystem
from vnhc_gym.systems.currents import CURRENTS, RANDOM_PARAM_NAMES, RANDOM_WEIGHTS, get_current
from vnhc_gym.systems.usv import USV_PRESETS, make_usv
from vnhc_gym.tasks.base import Task

Array = NDArray[np.float64]
__all__ = ["OBS_RATE_SCALE", "OBS_VEL_SCALE", "USVOptions", "USVStreamEnv", "USVTask", "USV_OBS_DIM"]

USV_OBS_DIM = 14
OBS_VEL_SCALE = 2.0  #: m/s: velocities and currents are divided by this in the observation
OBS_RATE_SCALE = 2.0  #: rad/s: the turn rate is divided by this


class Args(NamedTuple):
    """The USV hooks' constants."""

    amp_idx: np.ndarray  #: indices of the random current's amplitudes (empty for a fixed field)
    amp_w: np.ndarray  #: their standard deviations
    preset_state: np.ndarray  #: the preset's start state (unused without a preset)
    use_preset: bool
    domain: float  #: half-width of the charted square (m)


def task_params(key: jax.Array, p: jax.Array, args: Args) -> jax.Array:
    """`draw`'s stage 0: the random current's amplitudes ``amp_w[k] z_k``, ``z_k`` standard normal,
    into the nominal vector (before the mismatch, which then scales the drawn field).

    Parameters
    ----------
    key : jax.Array
        The episode's key for the task's own parameters.
    p : jax.Array, shape (n_params,)
        The task's nominal parameters.
    args : Args
        ``amp_idx`` and ``amp_w`` (zero-length for a fixed field: ``p`` is returned unchanged).

    Returns
    -------
    jax.Array, shape (n_params,)
        The episode's nominal parameters.
    """
    amp_idx = jnp.asarray(args.amp_idx)
    z = jax.random.normal(key, amp_idx.shape, p.dtype)  # a static shape: (0,) for a fixed field
    return p.at[amp_idx].set(jnp.asarray(args.amp_w, p.dtype) * z)


def initial(key: jax.Array, p: jax.Array, args: Args, *, system: ModuleType) -> jax.Array:
    """`draw`'s stages 1 and 2: the pose, then the velocity from the true current there, or the
    preset's start state.

    Position ``U(-5, 5)^2``, heading ``U(-pi, pi)``; velocity = current + ``U(0.5, 1.5)`` along the
    heading (raised to a ground speed of 0.3 m/s along the heading if needed) + ``±U(0.2, 1)``
    across it, so that ``|phi(0)| >= 0.2`` with the true parameters; turn rate ``U(-0.5, 0.5)``.

    Parameters
    ----------
    key : jax.Array
        The episode's key for the start state.
    p : jax.Array, shape (n_params,)
        The episode's true parameters (after the mismatch): the current the boat starts in.
    args : Args
        ``use_preset`` and ``preset_state``.
    system : module
        The printed USV system of the task's current (its ``outputs``: the current at the pose).

    Returns
    -------
    jax.Array, shape (6,)
        ``(x, y, theta, xd, yd, thetad)``.
    """
    dtype = p.dtype
    k_pose, k_speed, k_sign = jax.random.split(key, 3)
    x, y, theta = jax.random.uniform(k_pose, (3,), dtype, jnp.array([-5.0, -5.0, -math.pi], dtype),
                                     jnp.array([5.0, 5.0, math.pi], dtype))
    zero = jnp.zeros((), dtype)
    c1, c2 = system.outputs(jnp.stack([x, y, theta, zero, zero, zero]), p)[:2]  # the true current at the pose
    c, s = jnp.cos(theta), jnp.sin(theta)
    ahead, across, rate = jax.random.uniform(k_speed, (3,), dtype, jnp.array([0.5, 0.2, -0.5], dtype),
                                             jnp.array([1.5, 1.0, 0.5], dtype))
    # Forward through the water, and at least 0.3 m/s forward over ground along the heading:
    # on the manifold I thetadd = -m thetad v_forward, unstable when the boat goes backwards.
    forward = jnp.maximum(ahead, 0.3 - (c1 * c + c2 * s))
    phi0 = across * jax.random.rademacher(k_sign, (), dtype)  # off the manifold by construction
    # Velocity = current + forward speed along the heading + phi0 across it (mu = (sin, -cos)).
    drawn = jnp.stack([x, y, theta, c1 + forward * c + phi0 * s, c2 + forward * s - phi0 * c, rate])
    # The preset's start state every time (use_preset is traced under jit: a select, not a branch).
    return jnp.where(args.use_preset, jnp.asarray(args.preset_state, dtype), drawn)


def observation(s: jax.Array, phi: jax.Array, p: jax.Array, args: Args, *, system: ModuleType) -> jax.Array:
    """As `observe`: the heading, velocities, the nominal current map at the boat (value and
    gradient), the position and ``phi`` with the nominal current.

    Parameters
    ----------
    s : jax.Array, shape (6,)
    phi : jax.Array, shape (1,)
        Unused: the observation's ``phi`` is with the nominal current (what a chart gives).
    p : jax.Array, shape (n_params,)
        The nominal parameters: the current map a controller is told.
    args : Args
        ``domain``.
    system : module
        The printed USV system of the task's current.

    Returns
    -------
    jax.Array, shape (USV_OBS_DIM,)
    """
    aux = system.outputs(s, p)  # nominal C1, C2, dC1/dx, dC1/dy, dC2/dx, dC2/dy at the boat
    c, sn = jnp.cos(s[2]), jnp.sin(s[2])
    xd, yd = s[3], s[4]
    c1, c2 = aux[0], aux[1]
    head = jnp.stack([c, sn, xd / OBS_VEL_SCALE, yd / OBS_VEL_SCALE, s[5] / OBS_RATE_SCALE, c1 / OBS_VEL_SCALE,
                      c2 / OBS_VEL_SCALE, s[0] / args.domain, s[1] / args.domain,
                      (sn * xd - c * yd + c * c2 - sn * c1) / OBS_VEL_SCALE])  # phi with the nominal current
    return jnp.concatenate([head, aux[2:6]])  # the gradient (1/s): a controller's local affine model


#: The parameters of the controller's model (`USVTask.controller_model`, the affine current), in order.
CONTROLLER_PARAMS = ("m", "I", "current_scale", "c_c1", "c_c2", "c_j11", "c_j12", "c_j21", "c_j22")


def controller_inputs(obs: jax.Array, p: jax.Array, args: Args) -> tuple[jax.Array, jax.Array]:
    """The state ``(x, y, theta, xd, yd, thetad)`` and the affine current's parameters
    (`CONTROLLER_PARAMS`) read back from the observation, in a frame centred on the boat (``x = y = 0``).

    The law is the same in every frame (it depends on the current only through its value at the
    boat), and the centred frame keeps the noisy observed position out of it: the affine field
    ``C(p) = C0 + J p`` matches the observed (nominal) current ``C0`` and its gradient ``J`` at the
    boat, and its scale is 1 (the observed current already includes the nominal scale).  ``m`` and
    ``I`` are the first two nominal parameters of every current's model.
    """
    zero = jnp.zeros((), obs.dtype)
    s = jnp.stack([zero, zero, jnp.arctan2(obs[1], obs[0]), OBS_VEL_SCALE * obs[2], OBS_VEL_SCALE * obs[3],
                   OBS_RATE_SCALE * obs[4]])
    return s, jnp.stack([p[0], p[1], jnp.ones((), obs.dtype), OBS_VEL_SCALE * obs[5], OBS_VEL_SCALE * obs[6],
                         obs[10], obs[11], obs[12], obs[13]])


#: The parameters a Kalman filter estimates with the state (`USVTask.filtered_params`): the local
#: current, which changes as the boat moves through the field.
FILTERED_PARAMS = CONTROLLER_PARAMS[3:]


def recenter(s: jax.Array, p: jax.Array, args: Args) -> tuple[jax.Array, jax.Array]:
    """A state and affine current of the frame of `controller_inputs` one step on, in the frame
    centred on the boat anew: the current at the boat becomes the field's constant term (a filter's
    prediction, in the frame of the next observation)."""
    x, y = s[0], s[1]
    c1 = p[3] + p[5] * x + p[6] * y  # c_c1 + c_j11 x + c_j12 y
    c2 = p[4] + p[7] * x + p[8] * y  # c_c2 + c_j21 x + c_j22 y
    return s.at[0:2].set(0.0), p.at[3].set(c1).at[4].set(c2)


def parameter_drift(s: jax.Array, p: jax.Array, args: Args) -> jax.Array:
    """How the ground velocity moves with an unpredicted change of the current at the boat:
    ``d(xd, yd) = n n^T dC``, ``(6, len(FILTERED_PARAMS))``.

    The boat is pushed by ``W = m dV/dt`` with ``V = n n^T C`` the current's part across the
    heading ``n = (sin theta, -cos theta)``, so its velocity through that part of the water,
    ``w = qd - V``, has dynamics in which the current does not appear, and ``phi = n . w``.  A
    change of the current at the boat that the affine model does not predict (the field's
    curvature along the path) therefore carries the ground velocity with it; a filter that let
    the current drift alone would blur ``w``, and with it ``phi`` and the law.
    """
    n = jnp.stack([jnp.sin(s[2]), -jnp.cos(s[2])])
    return jnp.zeros((6, len(FILTERED_PARAMS)), s.dtype).at[3:5, 0:2].set(jnp.outer(n, n))


def unmodelled(s: jax.Array, p: jax.Array, c: jax.Array, args: Args, *, system: ModuleType) -> jax.Array:
    """Wind on the hull and quadratic cross-flow drag, which the model lacks, both across the hull
    (along the constraint's direction ``n = (sin theta, -cos theta)``): the wind's force ``c_0`` N,
    blowing towards the compass direction ``c_1`` (rad), pushes the hull's side with ``c_0 sin(theta
    - c_1)``; the drag is ``-c_2 |phi| phi``, against the sideways speed through the water (``phi``)."""
    slip = system.phi(s, p)[0]
    across = c[0] * jnp.sin(s[2] - c[1]) - c[2] * jnp.abs(slip) * slip
    return jnp.stack([across * jnp.sin(s[2]), -across * jnp.cos(s[2]), jnp.zeros((), s.dtype)]) / p[0]


@dataclass(frozen=True)
class USVOptions(TaskOptions):
    """The USV's own keyword arguments."""

    preset: str | None = option(None, "``\"paper-northeast\"``, ``\"paper-anticyclone\"``", choices=USV_PRESETS,
                                allow_none=True)
    current: str = option("random", "a name of ``vnhc_gym.systems.CURRENTS``", choices=CURRENTS)
    current_params: dict[str, float] | None = option(
        None, "overrides of the current's parameters (fixes a random field)")
    mass: float = option(10.0, "``m`` (kg)", low=0.0, low_open=True, high=1e12)
    inertia: float = option(1.5, "``I`` (kg m^2)", low=0.0, low_open=True, high=1e12)
    domain: float = option(100.0, "half-width of the charted square (m)", low=0.0, low_open=True, high=1e9)
    max_turn_rate: float = option(10.0, "largest physical turn rate (rad/s)", low=0.0, low_open=True, high=1e6)


class USVTask(Task):
    """A USV in a current held to ``phi = mu(qd - C) = 0`` (see [`USVStreamEnv`][vnhc_gym.tasks.usv.USVStreamEnv])."""

    name = "usv"
    Options = USVOptions
    #: The geometric law with the baseline's gain k = 5 needs at most ~57 N at the start of a nominal
    #: episode (500 seeds), so it never saturates at 100 N.
    default_force_bound = 100.0
    default_impulse_scale = 0.3
    #: Width of the bounded reward (m/s; chosen by experiments/reward_shape.py, see the docs).
    reward_sigma = 0.1
    phi_units = "m/s"
    phi_sf_scale = 1.0
    angles = (2,)  # theta
    uncertain = ("m", "I", "current_scale")
    #: Wind force (N) and the direction it blows to (rad), and the cross-flow drag (N s^2/m^2).
    unmodelled_ranges = {"wind_force": (10.0, 40.0), "wind_direction": (-math.pi, math.pi),
                         "crossflow_drag": (5.0, 50.0)}
    filtered_params = FILTERED_PARAMS  # the local current, read at the boat
    unmeasured = (7, 8)  # the position: the frame centred on the boat does not hold where the boat is

    def __init__(self, config: EnvConfig, options: USVOptions) -> None:
        super().__init__(config, options)
        preset, current, current_params = options.preset, options.current, options.current_params
        mass, inertia = options.mass, options.inertia
        if preset is not None:
            pr = USV_PRESETS[preset]
            current, mass, inertia, current_params = pr.current, pr.m, pr.inertia, None
        field = get_current(current)
        overrides: dict[str, float] = {}
        if current_params is not None:
            if not isinstance(current_params, dict):
                raise TypeError(f"current_params must be a dict of parameter name to number or None, "
                                f"got {current_params!r}")
            unknown = sorted(set(current_params) - set(field.defaults))
            if unknown:
                raise ValueError(f"current_params has unknown names {unknown} for current {current!r}; "
                                 f"valid: {sorted(field.defaults)}")
            for k, v in current_params.items():
                overrides[f"c_{k}"] = check_number(f"current_params[{k!r}]", v, low=-1e6, high=1e6)
        self.preset = preset
        self.current = current
        self.domain = options.domain
        self.max_turn_rate = options.max_turn_rate
        self.fixed_field = current != "random" or current_params is not None
        self.model = make_usv(current)
        names = self.model.param_names
        if names[:2] != ("m", "I") or self.controller_model().param_names != CONTROLLER_PARAMS:
            raise ValueError(f"task 'usv': controller_inputs reads m, I first and writes {CONTROLLER_PARAMS}, but the "
                             f"models' parameters are {names} and {self.controller_model().param_names}")
        self.nominal = self.model.params(m=mass, I=inertia, **overrides)
        self.obs_dim = USV_OBS_DIM
        self.impulse_mask = np.array([1.0, 1.0, 0.0])  # kicks on xd, yd
        amp_idx = [] if self.fixed_field else [names.index(f"c_{k}") for k in RANDOM_PARAM_NAMES]
        self.args = Args(
            amp_idx=np.array(amp_idx, dtype=np.intp),
            amp_w=np.asarray([] if self.fixed_field else RANDOM_WEIGHTS, dtype=np.float64),
            preset_state=USV_PRESETS[preset].state() if preset is not None else np.zeros(6),
            use_preset=preset is not None, domain=self.domain)
        self.limits = (("out_of_domain", 0, self.domain), ("out_of_domain", 1, self.domain),
                       ("turn_rate_exceeded", 5, self.max_turn_rate))

    # ------------------------------------------------------------------ what a controller reads
    def controller_model(self) -> ConstrainedSystem:
        """The USV with an affine current: the controller's local model of any current, from the
        current and its gradient that the observation gives at the boat."""
        return make_usv("affine")

    def informed_params(self, states: Array, params_true: Array) -> Array:
        """The affine current that matches the true field exactly at the boat (its value and gradient
        there, from the environment's own system at the true state), with the true mass and inertia,
        in the frame centred on the boat (see `controller_inputs`)."""
        model = self.controller_model()
        names, true_names = model.param_names, self.model.param_names
        local = self.model.outputs(np.asarray(states, dtype=np.float64), np.asarray(params_true, dtype=np.float64))
        p = np.tile(model.default_params, (local.shape[0], 1))
        for name in ("m", "I"):
            p[:, names.index(name)] = params_true[:, true_names.index(name)]
        p[:, names.index("current_scale")] = 1.0  # the field's values below include its scale
        for col, name in enumerate(("c_c1", "c_c2", "c_j11", "c_j12", "c_j21", "c_j22")):
            p[:, names.index(name)] = local[:, col]
        return p

    def scene(self, state: Array, phi: Array, params: Array) -> Scene:
        """The boat from above in its true current (a quiver), its velocity and its velocity
        through the water."""
        values = self.current_params(params)
        scale = float(params[self.model.param_names.index("current_scale")])
        field = get_current(self.current)

        def current(x: Array, y: Array) -> Array:
            return scale * field.value(x, y, values)

        return hull_scene(state, phi, current)

    def current_params(self, params: Array) -> dict[str, float]:
        """A parameter vector's current parameters, for `vnhc_gym.systems.currents.CurrentField`."""
        names = self.model.param_names
        return {k: float(params[names.index(f"c_{k}")]) for k in get_current(self.current).defaults}


class USVStreamEnv(ConstraintEnv):
    r"""A boat in a sea current held to an affine velocity constraint.

    ## Description

    A USV with configuration ``q = (x, y, theta)``, mass ``m`` and inertia ``I`` moves in a
    current ``C(x, y)``. One control force ``u`` acts along ``sin(theta) dx - cos(theta) dy +
    d theta``; the current pushes the boat with ``W = m dV/dt``. The task is the virtual affine
    constraint

    $$\phi = \sin\theta\,\dot x - \cos\theta\,\dot y + \cos\theta\,C^2 - \sin\theta\,C^1 = 0,$$

    i.e. no sideways velocity relative to the water. The stabilising law (derived; the printed one
    in the original paper is wrong, see the docs' errata) is
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

    The current's gradient gives a controller a local (affine) model of the current.

    ## Rewards

    ``r = exp(-|phi| / (1 m/s) / reward_sigma) - action_cost * a^2`` in ``[0, 1]`` (``-v1``, the
    default), with the true ``phi`` at the new state; ``-v0``: ``clip(-|phi| / phi_scale -
    action_cost * a^2, -reward_clip, 0)``. ``info["abs_phi"]`` is ``|phi|`` (m/s).

    ## Starting State

    Position ``U(-5, 5)^2`` m, heading ``U(-pi, pi)``, velocity = current + ``U(0.5, 1.5)`` m/s
    along the heading (raised if needed so that the ground speed along the heading is at least
    0.3 m/s) + ``±U(0.2, 1)`` m/s across it (so ``|phi(0)| >= 0.2``), turn rate
    ``U(-0.5, 0.5)`` rad/s. With ``current="random"`` a new field is drawn every episode.
    ``preset="paper-northeast"`` / ``"paper-anticyclone"`` reset to the paper's exact state.

    ## Episode End

    * Truncation: the time limit (``max_episode_steps=400`` with ``gym.make``: 20 s at the default
      ``dt``, 40 s under ``coarse``).
    * Termination: non-finite state (``"non_finite_state"``), the boat leaving the charted
      square ``|x|, |y| <= domain`` (``"out_of_domain"``) or spinning faster than
      ``max_turn_rate`` (``"turn_rate_exceeded"``), in ``info["termination_reason"]``. On the
      manifold ``I thetadd = -m thetad v``, with ``v`` the ground speed along the heading, which
      is unstable when the boat is pushed backwards (e.g. by a head current).

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
    | ``force_bound``   | 100.0     | largest force (N)                                           |
    | ``reward``        | "bounded" | ``"bounded"`` (``-v1``), ``"reciprocal"`` or ``"raw"`` (``-v0``) |
    | ``reward_sigma``  | 0.1       | width of the bounded reward                                 |
    | ``phi_scale``, ``reward_clip`` | 1, 100 | the raw reward's scale and clip                   |
    | ``action_cost``   | 0.0       | reward weight of ``a^2``                                    |
    | ``param_mismatch``| 0.0       | true ``m``, ``I``, current scale ``x (1 + U(-d, d))``       |
    | ``obs_noise``     | 0.0       | std of Gaussian observation noise                           |
    | ``impulse_prob``  | 0.0       | per-step probability of a random velocity kick             |
    | ``impulse_scale`` | 0.3       | std (m/s) of a kick on ``xd`` and ``yd``                    |
    | ``obs_clip``      | 10.0      | observation bound                                           |
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

    ``delay`` (2-6 steps), ``lag`` (0.1-0.5 s) and ``unmodelled``: the model wrong in structure,
    hidden from the controller and drawn again mid-episode, as for every task; ``unmodelled``:
    wind and cross-flow drag across the hull, neither of which the model has: the wind's
    ``w sin(theta - psi_w)``, ``w`` in ``U(10, 40)`` N blowing towards ``psi_w`` in ``U(-pi, pi)``, and
    ``-c_d |phi| phi``, ``c_d`` in ``U(5, 50)`` N s^2/m^2.

    ``delay_min``, ``delay_max``, ``lag_min``, ``lag_max`` (0), ``unmodelled`` (0) and ``redraw`` (False)
    set the hidden structure, as for every task.

    ## Info

    ``phi`` (float64 ``(1,)``), ``abs_phi``, ``abs_phi_sf`` (``|phi| / (1 m/s)``), ``state``
    (``x, y, theta, xd, yd, thetad``), ``force`` (N), ``time``; plus ``termination_reason`` when
    terminated. The info of ``reset`` also holds ``params`` (the episode's true ``m, I,
    current_scale, c_*``).
    Where the episode hides structure (``delay``, ``lag``, ``unmodelled``): ``delay_steps``,
    ``lag_time_constant`` (s) and ``unmodelled_coefficients``
    (``wind_force``, ``wind_direction``, ``crossflow_drag``), in force for the next step.

    ## Version History

    * v1: bounded reward ``exp(-|phi| / sigma)`` in ``[0, 1]``.
    * v0: the raw reward ``-|phi|``.
    """

    task_class = USVTask
    task: USVTask
