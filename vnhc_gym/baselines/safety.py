"""A safety filter for a task's declared velocity limits: any policy through a control barrier function.

An episode ends when a limited state entry leaves its bound (``Task.limits``: ``|x_i| > b_i``), and
every later step of the fixed horizon then scores 0.  The geometric law knows nothing of the
bounds: held to the constraint, a boat kicked sideways may be asked for a force that spins it past
its largest turn rate.  [`SafetyFilter`][vnhc_gym.baselines.SafetyFilter] leaves a base policy's
force alone where that is safe and changes it as little as possible where it is not.

For each limit on a *velocity* ``v = qd_k`` (a turn rate, a speed) it keeps the barrier

.. math::

    h = c^2 - v^2 \\ge 0, \\qquad c = (1 - \\text{margin})\\, b,

with the condition of a control barrier function on the nominal model (``qdd = f + B u``),

.. math::

    \\dot h = -2 v\\,(f_k + B_k u) \\ge -\\text{rate}\\; h ,

which is affine in the force: ``2 v B_k u <= rate h - 2 v f_k``.  Inside the margin it lets ``v``
approach ``c`` no faster than ``exp(-rate t)`` shrinks ``h``; beyond it (``h < 0``) it asks for
braking in proportion to how far ``v`` is past ``c``.  The square makes one barrier cover both
signs of ``v`` and keeps it smooth at ``v = 0``, where it never binds (``h = c^2 > 0``).  A bound
on a position (the cart's track, the boat's chart) has relative degree 2 in the force and is left
out: the filter only acts on velocity limits.

The filtered action is the one closest to the base's, in action units (so thrust in N and torque
in N m weigh alike), that meets every barrier and the force bound:

* one control: the barriers are half-lines of the action, their intersection with ``[-1, 1]`` an
  interval, and the nearest point of it is the base action clipped to it (closed form);
* several controls: a small quadratic programme, solved by OSQP (the ``control`` extra).  Only
  rows whose base action breaks a barrier are solved; the others keep the base action unchanged.

Where the force bound cannot meet a barrier, the action nearest to meeting it within the bound is
taken (the hardest braking); where barriers contradict each other, the base's action (clipped) is
kept.  The barrier is imposed at the start of each control period on the nominal model, so a
``margin`` keeps room for what the held force, the model's error and velocity kicks add; ``margin``
and ``rate`` are chosen on validation episodes like the law's gain
([`vnhc_gym.baselines.tuning`][vnhc_gym.baselines.tuning]).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from vnhc_gym.baselines.geometric import DEFAULT_GAIN, GeometricController
from vnhc_gym.baselines.policy import Policy, checked_task_of
from vnhc_gym.envs.config import check_number

__all__ = ["SafeLaw", "SafetyFilter", "project_box", "solve_qp", "velocity_limits"]

Array = NDArray[np.float64]

#: Default barrier settings: the velocity may come within 20 % of its bound, and ``h`` may shrink
#: at most as ``exp(-10 t)`` (a time constant of two 0.05 s control periods).
DEFAULT_MARGIN = 0.2
DEFAULT_RATE = 10.0


def velocity_limits(task: Any) -> tuple[tuple[str, int, float], ...]:
    """The task's limits on velocities, as ``(reason, k, bound)`` with ``k`` the velocity coordinate
    (the state entry ``n + k`` of the controller model's ``(q, qd)``).

    A limit indexes the environment's state; the controller's states
    ([`controller_inputs`][vnhc_gym.tasks.base.Task.controller_inputs]) index the same entries when
    both have the same size (a frame moved or turned with the body keeps every turn rate and, for a
    translation, every velocity: the shipped tasks' own and local models).  A controller model of
    another size has no limit the filter can read.
    """
    model = task.controller_model()
    n = int(model.n)
    if 2 * n != 2 * int(task.model.n):
        return ()
    return tuple((reason, int(i) - n, float(b)) for reason, i, b in task.limits if int(i) >= n)


def project_box(a0: Array, rows: Array, rhs: Array) -> tuple[Array, NDArray[np.bool_]]:
    """The nearest action to ``a0`` in ``[-1, 1]`` with ``rows * a <= rhs``, for one control (closed form).

    Parameters
    ----------
    a0 : ndarray, shape (B,)
        The base actions.
    rows, rhs : ndarray, shape (B, L)
        The barrier rows ``A`` (one coefficient each: one control) and right-hand sides ``b`` of
        ``A a <= b``.

    Returns
    -------
    (a, conflict)
        ``a`` of shape ``(B,)``; ``conflict`` marks the rows whose barriers contradict each other
        (there ``a`` is ``a0`` clipped).  A barrier the force cannot affect (``A = 0``) is left out.
        Where the interval the barriers leave lies outside ``[-1, 1]``, ``a`` is its nearest point
        of ``[-1, 1]``.
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        edge = rhs / rows
    upper = np.where(rows > 0, edge, np.inf).min(axis=1, initial=np.inf)
    lower = np.where(rows < 0, edge, -np.inf).max(axis=1, initial=-np.inf)
    conflict = lower > upper
    inside = np.clip(a0, np.where(conflict, -np.inf, lower), np.where(conflict, np.inf, upper))
    return np.clip(inside, -1.0, 1.0), conflict


def solve_qp(a0: Array, rows: Array, rhs: Array, box: bool = True) -> tuple[Array, NDArray[np.bool_]]:
    """The nearest actions to ``a0`` with ``A a <= b`` (and ``-1 <= a <= 1`` if ``box``), with OSQP.

    Parameters
    ----------
    a0 : ndarray, shape (B, m)
    rows : ndarray, shape (B, L, m)
    rhs : ndarray, shape (B, L)
    box : bool, default True
        Bound every action entry to ``[-1, 1]``.

    Returns
    -------
    (a, solved)
        ``a`` of shape ``(B, m)``, one programme per row; ``solved`` is False for rows OSQP found
        infeasible (or did not solve), where ``a`` is ``a0``.

    Raises
    ------
    ImportError
        If OSQP (the ``control`` extra: ``pip install vnhc-gym[control]``) is not installed.
    """
    try:
        import osqp
    except ImportError as exc:  # the filter with one control never gets here
        raise ImportError("the safety filter with several controls solves a quadratic programme with OSQP: "
                          "pip install 'vnhc-gym[control]' (or osqp)") from exc
    from scipy import sparse

    a0 = np.asarray(a0, dtype=np.float64)
    b, m = a0.shape
    n_lim = rows.shape[1]
    out = a0.copy()
    solved = np.ones(b, dtype=bool)
    if b == 0:
        return out, solved
    # One programme per row: a block-diagonal batch would be reported infeasible as a whole when
    # one row is, hiding the others' solutions (and the filter only solves the few rows it changes).
    eye = sparse.identity(m, format="csc")
    for r in range(b):
        block = sparse.csc_matrix(rows[r])
        a_mat = sparse.vstack([block, eye], format="csc") if box else block
        low = np.concatenate([np.full(n_lim, -np.inf), -np.ones(m)]) if box else np.full(n_lim, -np.inf)
        high = np.concatenate([rhs[r], np.ones(m)]) if box else rhs[r].copy()
        prob = osqp.OSQP()
        prob.setup(P=sparse.csc_matrix(2.0 * np.eye(m)), q=-2.0 * a0[r], A=a_mat, l=low, u=high, verbose=False,
                   eps_abs=1e-10, eps_rel=1e-10, polishing=True, max_iter=20000)
        res = prob.solve(raise_error=False)  # an infeasible row is reported in its status, not raised
        status = str(getattr(res.info, "status", "")).lower()
        if res.x is None or not np.all(np.isfinite(res.x)) or not status.startswith("solved"):
            solved[r] = False
            continue
        out[r] = res.x
    return out, solved


class SafetyFilter(Policy):
    """A base policy whose forces are filtered to keep the task's velocity limits (module docstring).

    Parameters
    ----------
    base : object with ``predict``
        The policy filtered (SB3 interface, actions in ``[-1, 1]``).  A stateful base gets
        ``episode_start`` forwarded and is told the action actually applied (``base.applied``).
    env : gymnasium Env or VectorEnv
        The vnhc_gym environment (its task's limits, controller model, force bound).
    margin : float, default 0.2
        Fraction of each bound kept free: the barrier is ``|v| <= (1 - margin) b``; in ``[0, 1)``.
    rate : float, default 10
        ``rate`` (1/s) of the barrier condition ``dh/dt >= -rate h``; > 0.

    Attributes
    ----------
    limits : tuple of (str, int, float)
        The velocity limits filtered (`velocity_limits`); empty: the filter returns the base's
        actions.
    n_filtered, n_rows : int
        Rows whose action the filter changed, and rows seen.
    """

    def __init__(self, base: Any, env: Any, margin: float = DEFAULT_MARGIN, rate: float = DEFAULT_RATE) -> None:
        if not hasattr(base, "predict"):
            raise TypeError(f"base must have a predict(obs) method, got {type(base).__name__}")
        margin = check_number("margin", margin, low=0.0, high=1.0)
        if margin >= 1.0:
            raise ValueError(f"margin must be in [0, 1), got {margin!r}")
        self.margin = margin
        self.rate = check_number("rate", rate, low=0.0, low_open=True, high=1e9)
        task = checked_task_of(env)
        self.base = base
        self.task = task
        self.model = task.controller_model()
        self.obs_dim = task.obs_dim
        self.act_dim = task.act_dim
        self.force_bound = np.asarray(task.force_bound, dtype=np.float64)
        self.limits = velocity_limits(task)
        self.name = f"safe({getattr(base, 'name', type(base).__name__)})"
        self.n_filtered = self.n_rows = 0

    def __repr__(self) -> str:
        return f"SafetyFilter({self.base!r}, margin={self.margin}, rate={self.rate})"

    @staticmethod
    def applies(task: Any) -> bool:
        """Whether the filter can ever change an action of ``task`` (it has a velocity limit)."""
        return bool(velocity_limits(task))

    def barriers(self, states: Array, params: Array) -> tuple[Array, Array]:
        """The barrier conditions ``A a <= b`` in action units at controller states: ``A`` of shape
        ``(B, L, m)``, ``b`` of shape ``(B, L)``, one row per velocity limit."""
        n = self.model.n
        f, y = self.model.dynamics(states, params)
        f = np.asarray(f).reshape(states.shape[0], n)
        y = np.asarray(y).reshape(states.shape[0], n, self.act_dim)
        rows = np.empty((states.shape[0], len(self.limits), self.act_dim))
        rhs = np.empty((states.shape[0], len(self.limits)))
        for j, (_, k, bound) in enumerate(self.limits):
            v = states[:, n + k]
            c = (1.0 - self.margin) * bound
            h = c * c - v * v
            # dh/dt = -2 v (f_k + B_k u) >= -rate h, with u = force_bound * a.
            rows[:, j] = (2.0 * v)[:, None] * y[:, k, :] * self.force_bound[None, :]
            rhs[:, j] = self.rate * h - 2.0 * v * f[:, k]
        return rows, rhs

    def filter(self, obs: Array, a0: Array) -> Array:
        """The filtered actions ``(B, m)`` for observations ``(B, d)`` and the base's actions ``a0``."""
        a = np.clip(np.where(np.isfinite(a0), a0, 0.0), -1.0, 1.0)
        if not self.limits:
            return a
        states, params = self.task.controller_inputs(obs)
        good = np.isfinite(states).all(axis=1) & np.isfinite(params).all(axis=1)
        positive = getattr(self.model, "param_positive", None)
        if positive is not None and np.any(positive):
            good &= np.all(params[:, np.asarray(positive, dtype=bool)] > 0, axis=1)
        if not good.any():
            return a
        idx = np.flatnonzero(good)
        rows, rhs = self.barriers(states[idx], params[idx])
        # A row already inside every barrier keeps its action exactly (the projection's fixed point).
        broken = np.any(np.einsum("blm,bm->bl", rows, a[idx]) > rhs, axis=1) & np.isfinite(rhs).all(axis=1) \
            & np.isfinite(rows).all(axis=(1, 2))
        if not broken.any():
            return a
        sel = idx[broken]
        r_sel, b_sel, a_sel = rows[broken], rhs[broken], a[sel]
        if self.act_dim == 1:
            new, _ = project_box(a_sel[:, 0], r_sel[:, :, 0], b_sel)
            a[sel, 0] = new
        else:
            new, solved = solve_qp(a_sel, r_sel, b_sel, box=True)
            if not solved.all():
                # The bound cannot meet the barriers: the nearest action meeting them, clipped.
                free, ok = solve_qp(a_sel[~solved], r_sel[~solved], b_sel[~solved], box=False)
                new[~solved] = np.clip(np.where(ok[:, None], free, a_sel[~solved]), -1.0, 1.0)
            a[sel] = new
        self.n_filtered += int(np.any(a[sel] != a0[sel], axis=1).sum())
        return a

    def predict(self, observation: ArrayLike, state: Any = None, episode_start: ArrayLike | None = None,
                deterministic: bool = True) -> tuple[NDArray[np.float32], Any]:
        """The base's actions through the filter, for one observation ``(d,)`` or a batch ``(n, d)``;
        ``episode_start`` and ``state`` go to the base, and the base is told the filtered action."""
        o, single = self.check_obs(observation)
        starts = None if episode_start is None else np.asarray(episode_start, dtype=bool).reshape(-1)
        if starts is not None and starts.shape[0] != o.shape[0]:
            raise ValueError(f"episode_start must have {o.shape[0]} entries, got {starts.shape[0]}")
        a0, state = self.base.predict(o, state=state, episode_start=starts, deterministic=deterministic)
        a0 = np.asarray(a0, dtype=np.float64).reshape(o.shape[0], self.act_dim)
        out = self.filter(o, a0).astype(np.float32)
        self.n_rows += o.shape[0]
        self.applied(out)
        return (out[0] if single else out), state

    def act(self, obs: Array) -> Array:
        a, _ = self.predict(obs)
        return np.asarray(a, dtype=np.float64).reshape(obs.shape[0], self.act_dim)

    def applied(self, action: ArrayLike) -> None:
        """Tell the base the action the environment received (a stateful base predicts with it)."""
        hook = getattr(self.base, "applied", None)
        if callable(hook):
            hook(action)

    def reset(self) -> None:
        hook = getattr(self.base, "reset", None)
        if callable(hook):
            hook()


class SafeLaw(SafetyFilter):
    """The geometric law (plain or sampled-data) through the safety filter: the ``safe_law`` baseline.

    Parameters
    ----------
    env : gymnasium Env or VectorEnv
    gain : float or array_like, default 5
        The law's ``diag K``.
    variant : {"plain", "sampled"}
        The law's variant ([`GeometricController`][vnhc_gym.baselines.GeometricController]).
    margin, rate : float
        The filter's settings ([`SafetyFilter`][vnhc_gym.baselines.SafetyFilter]).
    """

    def __init__(self, env: Any, gain: ArrayLike = DEFAULT_GAIN, variant: str = "plain",
                 margin: float = DEFAULT_MARGIN, rate: float = DEFAULT_RATE) -> None:
        super().__init__(GeometricController(env, gain=gain, variant=variant), env, margin=margin, rate=rate)
        self.name = "safe_law"

    def __repr__(self) -> str:
        return (f"SafeLaw({self.task.name!r}, variant={self.base.variant!r}, gain={self.base.gain.tolist()}, "
                f"margin={self.margin}, rate={self.rate})")
