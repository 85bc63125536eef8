"""Baseline policies with the Stable-Baselines3 ``predict`` interface.

* :class:`GeometricController` -- the paper's stabilising law (Theorem 2) computed from the
  **observation alone** plus the **nominal** model read once from the environment (masses and
  ``g``, or ``m`` and ``I``; ``dt``, ``substeps`` and the force bound).  Under ``mismatch`` it
  uses the wrong masses, under ``noisy`` the noisy observation: it is hurt honestly.
* :class:`ZeroPolicy` (no force) and :class:`RandomPolicy` (uniform actions, seeded).

All three accept a single environment, a wrapped one or a vector environment (then
``single_observation_space`` is used), and ``predict`` takes one observation ``(d,)`` or a
batch ``(n, d)`` and returns float32 actions in ``[-1, 1]`` (``u / force_bound``, clipped).  A
wrong observation shape raises ``ValueError`` naming the expected one.

The law from the observation
----------------------------
Flocking (``s = exp(5 o_logspeed)`` the leader's speed, ``e`` its direction, ``r_b = v_b / s``,
``p_b = phi_b / s^2``): ``phi_b = xd_N zd_b - xd_b zd_N = s^2 p_b`` and
``u*_b = m_b [g (xd_N - xd_b) - k_b phi_b] / (xd_N - zd_N)``; dividing numerator and denominator
by ``s``:

    u*_b = m_b [g (e_x - r_bx) - k_b s p_b] / (e_x - e_z).

``C`` is singular where ``e_x = e_z`` (leader moving along the diagonal): the action is then 0
for every follower, ``last_singular`` is True for that row and ``n_singular`` counts it.

USV (``o0, o1 = cos, sin``; velocities, turn rate and ``phi`` divided by 2 in the observation):

    u* = -m [k phi + thetad (xd cos(theta) + yd sin(theta))],

with ``phi`` the observed one (defined with the *nominal* current).

Sampled-data variant
--------------------
``variant="sampled"`` accounts for the zero-order hold: it rebuilds a state from the
observation and solves, by Newton's method through the compiled RK4 map of the nominal model
(:func:`vnhc_gym.mechanics.sampled_control`), for the held ``u`` with
``phi(after one period) = exp(-k dt) phi(now)``, using the env's ``dt`` and ``substeps``.

* Flocking: ``v_b = s r_b``, ``v_N = s e``, positions 0 (they enter neither the dynamics nor
  ``phi``).  The held motion is quadratic in time, so one Newton step is exact.
* USV: position ``(x, y) = domain * (o7, o8)``, heading ``atan2(sin, cos)``, velocities, and an
  *affine local model of the current* ``C(p) = C0 + J (p - p0)`` from the observed nominal
  current ``C0`` and Jacobian ``J`` (``make_usv("affine")`` with ``c = C0 - J p0``).

The model is used for the increment ``phi(F(x, u)) - phi(x)``, so rounding of the float32
observation does not bias the target.  Cost: about 0.5-1 ms per ``predict`` call (batched over
rows), against ~20 us for the plain law.

Measured residual (``experiments/sampled_residual.py``, ``results/sampled_residual.md``)
-----------------------------------------------------------------------------------------
Steady level = mean ``|phi|`` over the last half of 20 s episodes, nominal scenario, mean of
5 seeds, substeps 1; flocking ``phi`` in m^2/s^2 (the leader reaches ~200 m/s), USV in m/s.
"in-loop" is the law evaluated at every RK4 stage on the true state (reference).

========  ===  =====  ========  =========  =========
env        k    dt     plain     sampled    in-loop
========  ===  =====  ========  =========  =========
flocking   1   0.01   1.54e-04  2.02e-05   2.02e-05
flocking   1   0.05   6.86e-04  1.98e-05   1.98e-05
flocking   1   0.1    1.34e-03  1.94e-05   1.93e-05
flocking   5   0.01   2.34e-05  1.12e-08   6.45e-11
flocking   5   0.05   1.16e-04  2.74e-08   4.44e-08
flocking   5   0.1    2.30e-04  4.10e-08   8.02e-07
usv        1   0.01   3.03e-06  3.02e-06   3.02e-06
usv        1   0.05   3.14e-06  2.95e-06   2.92e-06
usv        1   0.1    3.42e-06  2.90e-06   0.339 (*)
usv        5   0.01   7.49e-09  6.75e-13   3.34e-10
usv        5   0.05   1.06e-07  4.09e-10   2.04e-07
usv        5   0.1    8.00e-07  1.81e-08   0.026 (*)
========  ===  =====  ========  =========  =========

With ``k = 1`` the exact decay ``exp(-t)`` itself still leaves ``~|phi(0)| e^-10 / 10`` in the
window, so the sampled variant (which reproduces ``exp(-k t)`` step by step) sits at that
transient level and the plain law's zero-order-hold floor shows only for flocking (8x at
``dt = 0.01`` to 69x at ``dt = 0.1`` above it).  With ``k = 5`` the floors appear: the plain
law's grows linearly with ``dt`` (flocking ~2e-4 at 0.1 s); the sampled variant is 3-4 orders
of magnitude lower for flocking (limited by float32 observation rounding) and 1e4x / 260x / 44x
lower for the USV at ``dt`` = 0.01 / 0.05 / 0.1 (limited by the random current's curvature,
which the affine local model lacks: in a uniform current, ``current="northeast"``, the sampled
variant reaches ~1e-9 at ``dt = 0.1``).  (*) With ``dt = 0.1`` and one RK4 substep, the
in-loop law makes the USV's closed loop stiff and one of the five episodes goes unstable
(the ``coarse`` scenario uses 4 substeps).  The held plain law has a related limit: its
yaw-rate term ``-m thetad (xd cos + yd sin)`` damps ``thetad`` at a rate ``(m/I) v_forward``
(~13/s at 2 m/s), so with ``k = 5`` and ``dt = 0.1`` it went unstable in 1 of 5 north-east
current episodes (boat left the domain); the sampled variant did not.

Over a whole episode (the benchmark's ``mean |phi|``), which the initial transient dominates,
the plain law scores *better* than the sampled one (flocking: by ~18 % at ``dt = 0.05`` and
~45 % at ``dt = 0.1``; USV: by 2-4 %): held, it decays slightly faster than ``exp(-k t)`` at first, the
sampled one exactly as ``exp(-k t)``; the benchmark's ``late_abs_phi`` (second half of the
episode) shows the floor instead.  (These numbers were measured with k = 1 and the force
bounds then in force, 100 N / 50 N; the defaults are now k = 5 with 250 N / 100 N, chosen so
that the law rarely saturates at the start of a nominal episode: see the env modules'
``DEFAULT_FORCE_BOUND``.)
"""

from vnhc_gym.baselines.geometric import DEFAULT_GAIN, EnvSpec, GeometricController, RandomPolicy, ZeroPolicy, env_spec

__all__ = ["DEFAULT_GAIN", "EnvSpec", "GeometricController", "RandomPolicy", "ZeroPolicy", "env_spec"]
