"""The core's argument checks and its singular test (``vnhc_gym.mechanics``).

Part one: every entry point of the core refuses a non-finite parameter (and a non-positive one
where the parameter is declared positive) with a ``ValueError`` that names the parameter and the
row, and the law's entry points refuse non-finite states by row, so that a ``SingularControlError``
always means a singular state.

Part two: the singular test is the transversality of the input fields to the constraint, measured
as the smallest singular value of ``C^{ba} / (|J_b| |Y^a|)`` with ``J = d phi/d qd`` and the sizes
taken in the metric.  Expected values are derived by hand (closed forms of the measure for the
flock, the USV, the sled and small test systems) or computed independently (numpy's SVD of the
hand-normalised matrix); decay is checked against ``exp(-k t)``.
"""

from __future__ import annotations

import pickle
from functools import cache

import numpy as np
import pytest
import sympy as sp

from vnhc_gym.mechanics import (
    FLAG_NONFINITE,
    FLAG_SINGULAR,
    ConstrainedSystem,
    MechanicalSystem,
    SingularControlError,
    VelocityConstraint,
    sampled_control,
    simulate,
)
from vnhc_gym.mechanics.fleet import FleetLayout
from vnhc_gym.systems import FLOCKING_PRESETS, make_flocking, make_sled, make_usv

NAN, INF = float("nan"), float("inf")
PAPER = FLOCKING_PRESETS["paper"]


def paper_state(gap: float | None = None) -> np.ndarray:
    """The paper's flocking state; with ``gap``, the leader's ``zd_4`` set so that ``xd_4 - zd_4 = gap``."""
    s = PAPER.state()
    if gap is not None:
        s[15] = s[11] - gap
    return s


def flock_measure_by_hand(s: np.ndarray, masses: np.ndarray) -> np.ndarray:
    """Per follower b of the 4-particle flock: C_bb = (xd_4 - zd_4)/m_b,
    |J_b|^2 = (xd_4^2 + zd_4^2)/m_b + (xd_b^2 + zd_b^2)/m_4 (phi^b also depends on the leader's
    velocity), |Y^b|^2 = 2/m_b; so the measure is
    |xd_4 - zd_4| / sqrt(2 (xd_4^2 + zd_4^2) + 2 (m_b/m_4)(xd_b^2 + zd_b^2))."""
    xd, zd = s[8:12], s[12:16]
    m = masses
    return np.abs(xd[3] - zd[3]) / np.sqrt(2 * (xd[3]**2 + zd[3]**2) + 2 * (m[:3] / m[3]) * (xd[:3]**2 + zd[:3]**2))


# =========================================================================== part one: refused arguments


@pytest.mark.parametrize(("name", "value", "expected"), [
    ("m", NAN, "finite"), ("m", INF, "finite"), ("I", INF, "finite"), ("I", -INF, "finite"),
    ("m", 0.0, "> 0"), ("m", -1.0, "> 0"), ("current_scale", 0.0, "> 0"),
])
def test_params_refuses_bad_values_by_name(name: str, value: float, expected: str) -> None:
    model = make_usv("northeast")
    with pytest.raises(ValueError, match=rf"'{name}' = {value}: expected .*{expected}"):
        model.params(**{name: value})


def test_params_accepts_any_finite_value_of_a_real_parameter() -> None:
    model = make_usv("northeast")
    assert model.param_positive == (True, True, True, False, False)  # m, I, scale declared positive; c_c1, c_c2 real
    p = model.params(m=1e10, c_c1=-3.0, c_c2=0.0)
    np.testing.assert_array_equal(p, [1e10, 1.5, 1.0, -3.0, 0.0])
    with pytest.raises(ValueError, match="'c_c1' = nan"):
        model.params(c_c1=NAN)


def test_mechanical_system_refuses_bad_defaults_by_name() -> None:
    x, xd = sp.symbols("x xd", real=True)
    m = sp.Symbol("m", positive=True)
    c = sp.Symbol("c", real=True)

    def build(values: dict[sp.Symbol, float]) -> MechanicalSystem:
        return MechanicalSystem("test_defaults", (x,), (xd,), sp.Matrix([[m]]), sp.Matrix([[1]]),
                                potential=c * x, params=values)

    for bad, pattern in (({m: NAN, c: 1.0}, "'m' = nan: expected a finite"), ({m: 2.0, c: INF}, "'c' = inf"),
                         ({m: 0.0, c: 1.0}, "'m' = 0.0: expected a number > 0"),
                         ({m: -2.0, c: 1.0}, "'m' = -2.0: .*declared positive")):
        with pytest.raises(ValueError, match=r"MechanicalSystem\(params=\.\.\.\): parameter " + pattern):
            build(bad)
    system = build({m: 2.0, c: -4.0})  # a real parameter may be negative
    assert system.param_positive == (True, False)
    assert system.default_param_values({"c": -1.0}) == [2.0, -1.0]
    with pytest.raises(ValueError, match="'m' = -1.0"):
        system.default_param_values({"m": -1.0})
    with pytest.raises(ValueError, match="'c' = nan"):
        system.default_param_values({"c": NAN})


def test_fleet_layout_refuses_non_finite_defaults() -> None:
    with pytest.raises(ValueError, match="'k' = nan: expected a finite number"):
        FleetLayout("test_bad_defaults", 2, np.array([[0, 2], [1, 3]]), np.array([[0], [0]]), np.array([True]),
                    ("k",), (NAN,))


def _batch_with_bad_row(model: ConstrainedSystem, name: str, value: float, rows: int = 4, bad: int = 2) -> np.ndarray:
    p = np.tile(model.default_params, (rows, 1))
    p[bad, model.param_names.index(name)] = value
    return p


@pytest.mark.parametrize(("value", "expected"), [(NAN, "finite"), (INF, "finite"), (0.0, "> 0"), (-2.0, "> 0")])
def test_control_refuses_a_bad_parameter_row_by_name(value: float, expected: str) -> None:
    """Not a SingularControlError: the message names the row and the parameter, not the geometry."""
    model = make_flocking(4)
    s = np.tile(paper_state(), (4, 1))
    p = _batch_with_bad_row(model, "m_2", value)
    with pytest.raises(ValueError, match=rf"params row 2: parameter 'm_2' = {value}: expected .*{expected}"):
        model.control(s, params=p)
    with pytest.raises(ValueError, match="params row 2: parameter 'm_2'"):
        model.control(s, params=p, on_singular="flag")
    with pytest.raises(ValueError, match="params row 2: parameter 'm_2'"):
        model.invariance_control(s, params=p)
    # One vector (every row is it): named without a row.
    with pytest.raises(ValueError, match=r"^params: parameter 'm_2'"):
        model.control(s, params=p[2])


def test_control_counts_the_other_bad_rows() -> None:
    model = make_flocking(4)
    p = np.tile(model.default_params, (5, 1))
    p[1, 0] = NAN
    p[3, 4] = -1.0  # g, declared positive
    p[4, 2] = INF
    with pytest.raises(ValueError, match=r"params row 1: parameter 'm_1' = nan: .*\(2 more rows also invalid\)"):
        model.control(np.tile(paper_state(), (5, 1)), params=p)


@pytest.mark.parametrize("feedback", ["open", "continuous", "sampled"])
def test_step_refuses_a_bad_parameter_row_by_name(feedback: str) -> None:
    model = make_usv("northeast")
    s = np.tile([1.0, 1.0, np.pi / 2, 0.8, 0.5, 0.0], (4, 1))
    with pytest.raises(ValueError, match="params row 2: parameter 'I' = inf"):
        model.step(s, 0.01, feedback=feedback, params=_batch_with_bad_row(model, "I", INF))  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="params row 2: parameter 'm' = 0.0: expected a number > 0"):
        model.step(s, 0.01, feedback=feedback, params=_batch_with_bad_row(model, "m", 0.0))  # type: ignore[arg-type]


@pytest.mark.parametrize("feedback", ["open", "continuous", "sampled"])
def test_simulate_refuses_a_nan_mass_by_name(feedback: str) -> None:
    """Without the check, the run returns flag 3 and phi = NaN."""
    model = make_usv("northeast")
    s0 = np.array([1.0, 1.0, np.pi / 2, 0.8, 0.5, 0.0])
    with pytest.raises(ValueError, match=r"^params: parameter 'm' = nan: expected a finite number"):
        simulate(model, s0, 0.01, 10, feedback=feedback, params=model.params() * [NAN, 1, 1, 1, 1])  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="params row 1: parameter 'm' = nan"):
        simulate(model, np.stack([s0, s0]), 0.01, 10, feedback=feedback,  # type: ignore[arg-type]
                 params=_batch_with_bad_row(model, "m", NAN, rows=2, bad=1))


def test_sampled_control_refuses_bad_parameters_states_and_phi_by_row() -> None:
    model = make_flocking(4)
    s = np.tile(paper_state(), (3, 1))
    with pytest.raises(ValueError, match="params row 1: parameter 'g' = nan"):
        sampled_control(model, s, _batch_with_bad_row(model, "g", NAN, rows=3, bad=1), 0.01)
    with pytest.raises(ValueError, match="params row 1: parameter 'm_4' = -2.0"):
        sampled_control(model, s, _batch_with_bad_row(model, "m_4", -2.0, rows=3, bad=1), 0.01)
    bad = s.copy()
    bad[2, 9] = NAN
    with pytest.raises(ValueError, match=r"state row 2: entry 9 \(qd\[1\]\) = nan"):
        sampled_control(model, bad, None, 0.01)
    phi_now = np.zeros((3, 3))
    phi_now[1, 0] = INF
    with pytest.raises(ValueError, match=r"phi_now row 1 = \[inf, 0.0, 0.0\]"):
        sampled_control(model, s, None, 0.01, phi_now=phi_now)


def test_law_refuses_non_finite_states_by_row() -> None:
    """The law is not evaluated at a non-finite state (its C would be NaN, and the state
    reported as singular); the open-loop integrator integrates it and flags it."""
    model = make_flocking(4)
    s = np.tile(paper_state(), (3, 1))
    s[1, 3] = INF
    s[2, 0] = NAN
    with pytest.raises(ValueError, match=r"state row 1: entry 3 \(q\[3\]\) = inf: .*\(1 more row also non-finite\)"):
        model.control(s)
    with pytest.raises(ValueError, match=r"^state: entry 3 \(q\[3\]\) = inf"):
        model.control(s[1])
    for feedback in ("continuous", "sampled"):
        with pytest.raises(ValueError, match="state row 1: entry 3"):
            model.step(s, 0.01, feedback=feedback)  # type: ignore[arg-type]
        with pytest.raises(ValueError, match="state row 1: entry 3"):
            simulate(model, s, 0.01, 3, feedback=feedback)  # type: ignore[arg-type]
    _, _, flags = model.step(s, 0.01, feedback="open")
    assert flags.tolist() == [0, FLAG_NONFINITE, FLAG_NONFINITE]


def test_singular_tol_must_be_finite_and_positive() -> None:
    x, xd = sp.symbols("x xd", real=True)
    system = MechanicalSystem("test_tol", (x,), (xd,), sp.Matrix([[1]]), sp.Matrix([[1]]))
    for bad in (0.0, -1e-10, NAN, INF):
        with pytest.raises(ValueError, match="singular_tol"):
            ConstrainedSystem(system, VelocityConstraint(sp.Matrix([xd])), singular_tol=bad)


def test_parameter_signs_survive_pickling() -> None:
    model = pickle.loads(pickle.dumps(make_usv("northeast")))
    assert model.param_positive == (True, True, True, False, False)
    with pytest.raises(ValueError, match="'I' = -1.0"):
        model.params(I=-1.0)


# =========================================================================== part two: the singular test


def test_flock_near_the_singular_set_is_flagged_at_any_mass() -> None:
    """At the paper's state with xd_4 - zd_4 = 1e-13, C = 1e-13 diag(1/m_b): a uniformly tiny C
    that a test relative to max|C| passes.  The followers can barely change the cross product."""
    model = make_flocking(4)
    near = paper_state(1e-13)
    for mass in (2.0, 1e8, 1e-8):
        p = model.params(**{f"m_{i}": mass for i in range(1, 5)})
        np.testing.assert_allclose(model.transversality(near, p), flock_measure_by_hand(near, p[:4]).min(),
                                   rtol=1e-6)
        assert model.transversality(near, p) < 1e-12
        with pytest.raises(SingularControlError, match=r"singular state at batch rows \[1\]") as info:
            model.control(np.stack([paper_state(), near]), params=p)
        assert info.value.rows.tolist() == [1]
        assert info.value.measure is not None and info.value.measure[0] < 1e-12
        assert "param" not in str(info.value)
        u, singular = model.control(np.stack([paper_state(), near]), params=p, on_singular="flag")
        assert singular.tolist() == [False, True] and np.all(u[1] == 0.0) and np.all(np.isfinite(u))
        for feedback in ("continuous", "sampled"):
            flags = model.step(np.stack([paper_state(), near]), 0.01, feedback=feedback, params=p)[2]  # type: ignore[arg-type]
            assert [bool(f & FLAG_SINGULAR) for f in flags] == [False, True]


@pytest.mark.parametrize("mass", [1e8, 1e-8])
def test_flock_far_from_the_singular_set_works_at_any_mass(mass: float) -> None:
    """The paper's state with every mass 1e8 or 1e-8: not flagged, and phi decays as exp(-k t)."""
    model = make_flocking(4)
    p = model.params(**{f"m_{i}": mass for i in range(1, 5)})
    s0 = paper_state()
    np.testing.assert_allclose(model.transversality(s0, p), flock_measure_by_hand(s0, p[:4]).min(), rtol=1e-13)
    gains = np.array([1.0, 2.0, 0.5])
    # By hand: u_b = m_b [g (xd_4 - xd_b) - k_b phi_b] / (xd_4 - zd_4); phi = (0.6, 0.6, -0.6) here.
    xd, zd = s0[8:12], s0[12:16]
    phi0 = xd[3] * zd[:3] - xd[:3] * zd[3]
    np.testing.assert_allclose(model.phi(s0, p), phi0, rtol=1e-15)
    u = model.control(s0, gains=gains, params=p)
    np.testing.assert_allclose(u, mass * (10.0 * (xd[3] - xd[:3]) - gains * phi0) / (xd[3] - zd[3]), rtol=1e-13)
    tr = simulate(model, s0, 0.01, 300, gains=gains, params=p)
    assert not np.any(tr.flags)
    np.testing.assert_allclose(tr.phi, np.exp(-np.outer(tr.t, gains)) * phi0, rtol=1e-6, atol=1e-12)


def test_flock_followers_of_very_different_masses_are_not_singular() -> None:
    """Masses 1e-6 and 1e6 make the blocks of C differ by 1e12: each follower is as steerable as
    the others, so the verdict is the same as with equal masses, and phi decays as exp(-k t)."""
    model = make_flocking(4)
    p = model.params(m_1=1e-6, m_2=1.0, m_3=1e6)
    s0 = paper_state()
    c, _ = model.decoupling(s0, p)
    assert c[2, 2] / c[0, 0] == pytest.approx(1e-12)
    np.testing.assert_allclose(model.transversality(s0, p), flock_measure_by_hand(s0, p[:4]).min(), rtol=1e-13)
    tr = simulate(model, s0, 0.01, 200, gains=1.0, params=p)
    assert not np.any(tr.flags)
    phi0 = tr.phi[0]
    np.testing.assert_allclose(tr.phi, np.exp(-tr.t)[:, None] * phi0, rtol=1e-5, atol=1e-12)  # RK4 at dt = 0.01


@pytest.mark.parametrize("mass", [1e-10, 1.0, 10.0, 1e10])
def test_usv_measure_and_law_at_any_mass(mass: float) -> None:
    """C = 1/m, |J|^2 = 1/m (J = (sin, -cos, 0)), |Y|^2 = f . Y = 1/m + 1/I: the measure is
    1/sqrt(1 + m/I), whatever the state; at m = 1e10 it is about 1e-5, far above the tolerance."""
    model = make_usv("northeast")
    p = model.params(m=mass)
    rng = np.random.default_rng(3)
    s = np.column_stack([rng.uniform(-3, 3, (6, 2)), rng.uniform(-np.pi, np.pi, 6), rng.uniform(-2, 2, (6, 3))])
    np.testing.assert_allclose(model.transversality(s, p), 1.0 / np.sqrt(1.0 + mass / 1.5), rtol=1e-13)
    u = model.control(s, gains=2.0, params=p)
    x, y, th, xd, yd, thd = s.T
    phi = np.sin(th) * (xd - 1.0) - np.cos(th) * (yd - 1.0)
    np.testing.assert_allclose(u[:, 0], -mass * (2.0 * phi + thd * (xd * np.cos(th) + yd * np.sin(th))),
                               rtol=1e-10, atol=1e-12 * mass)


def test_sled_measure_is_the_offset_of_its_mass() -> None:
    """C = [[0, -a/I], [1/m, 0]], |J_1|^2 = 1/m + a^2/I, |J_2|^2 = 1/m, |Y^1|^2 = 1/m, |Y^2|^2 = 1/I:
    the normalised C is [[0, -a/sqrt(I/m + a^2)], [1, 0]], whose smallest singular value is
    a / sqrt(I/m + a^2); the slip cannot be steered when the mass sits on the blade (a -> 0)."""
    model = make_sled()
    rng = np.random.default_rng(4)
    s = rng.uniform(-2, 2, (5, 6))
    for m, inertia, a in ((20.0, 2.0, 0.3), (2e7, 2e6, 0.3), (1.0, 50.0, 2.0)):
        p = model.params(m=m, I=inertia, a=a)
        np.testing.assert_allclose(model.transversality(s, p), a / np.sqrt(inertia / m + a * a), rtol=1e-13)
    p = model.params(a=1e-12)
    with pytest.raises(SingularControlError) as info:
        model.control(s, params=p)
    assert info.value.rows.tolist() == [0, 1, 2, 3, 4]


@cache
def gravity_particle() -> ConstrainedSystem:
    """A particle of mass m in the vertical xz-plane under gravity, pushed along x, held to
    phi = x xd + zd: J = (x, 1), Y = (1/m, 0), so C = x/m and the inputs are tangent to the
    constraint at x = 0 (phi then depends only on zd, which the push cannot change)."""
    x, z, xd, zd = sp.symbols("x z xd zd", real=True)
    m, g = sp.symbols("m g", positive=True)
    system = MechanicalSystem("test_gravity_particle", (x, z), (xd, zd), m * sp.eye(2), sp.Matrix([1, 0]),
                              potential=m * g * z, params={m: 1.4, g: 9.81})
    return ConstrainedSystem(system, VelocityConstraint(sp.Matrix([x * xd + zd])))


def test_gradient_nearly_orthogonal_to_the_input_is_flagged() -> None:
    """The measure is |x| / sqrt(1 + x^2) (|J|^2 = (x^2 + 1)/m, |Y|^2 = 1/m); by hand
    G = xd^2 - g, so u* = m (-k phi - xd^2 + g) / x, which grows without bound as x -> 0."""
    model = gravity_particle()
    s = np.array([[0.5, 2.0, -0.3, 1.2], [1e-13, 2.0, -0.3, 1.2], [-2.0, 0.0, 0.7, -0.1]])
    x, _, xd, zd = s.T
    np.testing.assert_allclose(model.transversality(s), np.abs(x) / np.sqrt(1 + x * x), rtol=1e-14)
    u, singular = model.control(s, gains=3.0, on_singular="flag")
    assert singular.tolist() == [False, True, False]
    ok = [0, 2]
    phi = x * xd + zd
    np.testing.assert_allclose(u[ok, 0], 1.4 * (-3.0 * phi[ok] - xd[ok] ** 2 + 9.81) / x[ok], rtol=1e-13)
    with pytest.raises(SingularControlError) as info:
        model.control(s)
    assert info.value.rows.tolist() == [1]
    # The verdict does not depend on the mass: a C of 1e-13/m is singular at m = 1e-13 too.
    for mass in (1e-13, 1.0, 1e13):
        assert model.control(s, params=[mass, 9.81], on_singular="flag")[1].tolist() == [False, True, False]


@cache
def scaled_constraint() -> ConstrainedSystem:
    """A unit mass on a line with phi = c xd: C = c, |J| = |c|, |Y| = 1, so the measure is 1 for
    every c != 0 (rescaling the constraint changes nothing) and 0 for c = 0 (no constraint)."""
    x, xd = sp.symbols("x xd", real=True)
    c = sp.Symbol("c", real=True)
    system = MechanicalSystem("test_scaled_constraint", (x,), (xd,), sp.Matrix([[1]]), sp.Matrix([[1]]),
                              params={c: 1.0})
    return ConstrainedSystem(system, VelocityConstraint(sp.Matrix([c * xd])))


def test_rescaling_the_constraint_never_changes_the_verdict() -> None:
    model = scaled_constraint()
    s = np.array([0.3, -2.0])
    for scale in (1e-150, 1e-12, -1.0, 1e12, 1e150):
        assert model.transversality(s, [scale]) == pytest.approx(1.0, rel=1e-15)
        assert model.control(s, gains=2.0, params=[scale])[0] == pytest.approx(4.0, rel=1e-15)  # u = -k xd
    assert model.transversality(s, [0.0]) == 0.0
    with pytest.raises(SingularControlError):
        model.control(s, params=[0.0])


@cache
def three_inputs() -> ConstrainedSystem:
    """Three coordinates with masses m_i, pushed by F(q) = [[1, x, 0], [0, 1, y], [1, 0, 1]] (a full,
    3 x 3 decoupling matrix C = M^-1 F), held to rest (phi = qd)."""
    q = sp.symbols("x y w", real=True)
    qd = sp.symbols("xd yd wd", real=True)
    masses = sp.symbols("m_1:4", positive=True)
    x, y, _ = q
    forces = sp.Matrix([[1, x, 0], [0, 1, y], [1, 0, 1]])
    system = MechanicalSystem("test_three_inputs", q, qd, sp.diag(*masses), forces,
                              params=dict(zip(masses, (1.0, 2.0, 3.0), strict=True)))
    return ConstrainedSystem(system, VelocityConstraint(sp.Matrix(qd)))


def test_full_decoupling_matrix_measure_is_the_smallest_singular_value() -> None:
    """|J_b|^2 = 1/m_b (J = I), |Y^a|^2 = f^a . M^-1 f^a; numpy's SVD of the normalised C."""
    model = three_inputs()
    rng = np.random.default_rng(5)
    s = rng.uniform(-2, 2, (6, 6))
    masses = np.array([0.7, 3.0, 1e6])
    got = model.transversality(s, masses)
    for r in range(6):
        f = np.array([[1, s[r, 0], 0], [0, 1, s[r, 1]], [1, 0, 1]])
        c = f / masses[:, None]
        jn = 1 / masses
        yn = np.einsum("ia,ia->a", f, f / masses[:, None])
        normalised = c / np.sqrt(jn)[:, None] / np.sqrt(yn)[None, :]
        assert got[r] == pytest.approx(np.linalg.svd(normalised, compute_uv=False).min(), rel=1e-12)
    # det F = 1 + x y = 0 on the hyperbola y = -1/x: there the state is singular.
    on = s[:2].copy()
    on[:, 1] = -1.0 / on[:, 0]
    assert np.all(model.transversality(on, masses) < 1e-14)
    assert model.control(on, params=masses, on_singular="flag")[1].tolist() == [True, True]


def transversality(blocks: np.ndarray, sizes: np.ndarray) -> float:
    """`functional.measure` of the block-diagonal matrix whose blocks are stored by block rows in
    ``blocks`` ``(m, k)``."""
    import jax

    from vnhc_gym.mechanics import functional as F

    m, k = blocks.shape
    full = np.zeros((m, m))
    for row in range(m):
        start = row // k * k
        full[row, start:start + k] = blocks[row]
    with jax.enable_x64(True):
        return float(F.measure(full, sizes))


@pytest.mark.parametrize("k", [1, 2, 3, 4])
def test_transversality_measure_against_numpy(k: int) -> None:
    """The measure on random block-diagonal matrices: the smallest singular value over the blocks of
    the matrix with rows and columns divided by the sizes (numpy's SVD, block by block)."""
    rng = np.random.default_rng(10 + k)
    m = 4 if k != 3 else 6
    for _ in range(20):
        c = rng.normal(size=(m, k)) * 10.0 ** rng.uniform(-5, 5)
        sizes = 10.0 ** rng.uniform(-6, 6, 2 * m)
        want = np.inf
        for blk in range(0, m, k):
            block = c[blk:blk + k] / np.sqrt(sizes[blk:blk + k])[:, None] / np.sqrt(sizes[m + blk:m + blk + k])
            want = min(want, np.linalg.svd(block, compute_uv=False).min())
        assert transversality(c, sizes) == pytest.approx(want, rel=1e-10)
    # Every block scaled by its own factor, every size likewise: the same measure.
    c = rng.normal(size=(m, k))
    sizes = rng.uniform(0.5, 2, 2 * m)
    row_scale = np.repeat(10.0 ** rng.uniform(-100, 100, m // k), k)
    scaled = c * row_scale[:, None] ** 2
    scaled_sizes = np.concatenate([sizes[:m] * row_scale**2, sizes[m:] * row_scale**2])
    assert transversality(scaled, scaled_sizes) == pytest.approx(transversality(c, sizes), rel=1e-12)


@pytest.mark.parametrize("k", [1, 2, 3])
def test_transversality_measure_on_degenerate_and_bad_input(k: int) -> None:
    m = 3 * k
    rng = np.random.default_rng(20 + k)
    c = rng.normal(size=(m, k))
    sizes = np.ones(2 * m)
    assert 0.0 < transversality(c, sizes)
    zero = c.copy()
    zero[k:2 * k] = 0.0  # the second block vanishes
    assert transversality(zero, sizes) == 0.0
    for where in (1, m + 1):  # a zero size, of a row of J and of an input field, with C's row/column zero
        z, zs = c.copy(), sizes.copy()
        zs[where] = 0.0
        if where < m:
            z[where] = 0.0
        else:
            z[(where - m) // k * k:(where - m) // k * k + k, (where - m) % k] = 0.0
        assert transversality(z, zs) == 0.0
    for bad in (NAN, INF):
        cb = c.copy()
        cb[m - 1, k - 1] = bad
        assert np.isnan(transversality(cb, sizes))
        sb = sizes.copy()
        sb[m] = bad
        assert np.isnan(transversality(c, sb))
