"""A sampled-data (zero-order hold) version of the stabilising law.

The law of Theorem 2 makes ``d phi/dt = -K phi`` when it is re-evaluated continuously.  An
RL environment (and any digital controller) instead holds one control value over a control
period ``dt``; held, ``u*`` no longer gives ``phi(t + dt) = exp(-K dt) phi(t)`` because the
drift changes inside the period, and ``phi`` levels off at a small but nonzero value (see
the docs' math page, "the sampled-data fact").

[`sampled_control`][vnhc_gym.mechanics.sampled_control] chooses the held control so that the
*discrete* closed loop is the exact discretisation of the continuous one,

.. math::

    \\phi\\big(F_{dt}(x, u)\\big) = e^{-K\\,dt}\\,\\phi(x),

where ``F_dt`` is the RK4 step map of the model over one control period (open loop, ``u``
held; the same map an environment integrates with).  The ``m`` equations in ``m`` unknowns are
solved by Newton's method, started from ``u*``, with the exact Jacobian by forward-mode
differentiation of the RK4 step (`vnhc_gym.mechanics.functional.sampled_law`, run on every batch
row in one compiled call).  For the flocking system the equation is
affine in ``u`` (the held motion is a polynomial of degree two in time, which RK4 integrates
exactly), so a single Newton step solves it to rounding error.

Nothing here imports Gymnasium.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from vnhc_gym.mechanics import functional as F
from vnhc_gym.mechanics.model import ConstrainedSystem

__all__ = ["sampled_control"]

Array = NDArray[np.float64]


def sampled_control(model: ConstrainedSystem, states: ArrayLike, params: ArrayLike | None, dt: float,
                    gains: ArrayLike | None = 1.0, substeps: int = 1, iters: int = 4, *,
                    phi_now: ArrayLike | None = None, xtol: float = 1e-10,
                    ) -> tuple[Array, NDArray[np.bool_] | bool]:
    """Held control that makes ``phi`` after one control period equal ``exp(-K dt) phi_now``.

    Parameters
    ----------
    model : ConstrainedSystem
        A system with a *velocity* constraint (holonomic constraints are not supported).
    states : array_like, shape (2n,) or (B, 2n)
        Finite.
    params : array_like or None
        Model parameters, ``(n_params,)`` or ``(B, n_params)`` (``None``: defaults); finite, and
        > 0 where declared positive (``model.param_positive``).
    dt : float
        Control period over which the control is held (> 0).
    gains : scalar or array_like, default 1
        ``diag K`` (``m`` values, or a scalar), each >= 0.
    substeps : int, default 1
        RK4 steps per control period (use the environment's value).
    iters : int, default 4
        Largest number of Newton updates.
    phi_now : array_like, optional, shape (m,) or (B, m)
        A measured value of ``phi`` at ``states``.  The target is then ``exp(-K dt) phi_now``
        and the model is used for the *increment*: the equation solved is
        ``phi(F(x, u)) - phi(x) = (exp(-K dt) - 1) phi_now``, so a bias between the model's
        ``phi(x)`` and the measurement (a state rebuilt from rounded observations, a local
        model of a current) cancels.  Default: ``phi(states)`` (then both forms coincide).
    xtol : float, default 1e-10
        A row has converged when its residual is exactly zero or its last Newton step is at
        most ``xtol * max(1, |u|)`` in every component.

    Returns
    -------
    (u, converged)
        ``u`` of shape ``(m,)`` or ``(B, m)``; ``converged`` a bool or ``(B,)`` bool array.
        Where Newton fails (singular Jacobian, non-finite values, a singular ``C`` at the
        start, or no convergence within ``iters``) ``converged`` is False; ``u`` is then the
        last finite iterate (at worst ``u*``, or 0 where ``C`` is singular).
        No saturation is applied: clip ``u`` to the actuator bounds yourself.

    Raises
    ------
    ValueError
        If a parameter, a state or ``phi_now`` is not finite (or a parameter declared positive is
        not > 0); the message names the row and the entry.
    """
    if model.holonomic:
        raise ValueError("sampled_control supports velocity constraints only (the model's constraint is holonomic)")
    if not (np.isfinite(dt) and dt > 0):
        raise ValueError(f"dt must be a finite number > 0, got {dt}")
    if int(substeps) != substeps or substeps < 1:
        raise ValueError(f"substeps must be an integer >= 1, got {substeps}")
    if int(iters) != iters or iters < 0:
        raise ValueError(f"iters must be an integer >= 0, got {iters}")
    if not (np.isfinite(xtol) and xtol >= 0):
        raise ValueError(f"xtol must be a finite number >= 0, got {xtol}")
    s, single = model._states(states)
    b, m = s.shape[0], model.m
    p = model._params(params, b)
    k = model._gains(gains, b)
    model._law_states(s, single)
    if phi_now is None:
        measured = model._run(("phi",), lambda: model.functions.phi, (s, p))
    else:
        given = np.asarray(phi_now, dtype=np.float64)
        measured = np.ascontiguousarray(np.broadcast_to(given.reshape(1, -1) if given.ndim == 1 else given, (b, m)))
        if not np.all(np.isfinite(measured)):
            row = int(np.argwhere(~np.isfinite(measured))[0][0])
            where = f"phi_now row {row}" if given.ndim == 2 else "phi_now"
            raise ValueError(f"{where} = {measured[row].tolist()}: expected finite values")
    functions, tol, n_sub, n_it = model.functions, model.singular_tol, int(substeps), int(iters)

    def make():  # type: ignore[no-untyped-def]
        return lambda x, q, g, now, h, xt: F.sampled_law(functions, x, q, h, g, n_sub, n_it, phi_now=now, xtol=xt,
                                                          singular_tol=tol)

    u, converged = model._run(("sampled", n_sub, n_it), make, (s, p, k, measured), (float(dt), float(xtol)))
    if single:
        return u[0], bool(converged[0])
    return u, converged
