"""Generated code: the template module on its placeholder system, the generated expression functions
against independent evaluations (sympy itself, numpy formulas), the cache keys, the recipe-keyed
models, and the loader's checks of a cache entry (in this process; ``test_cache.py`` runs fresh
processes)."""

from __future__ import annotations

import hashlib
import math
import pickle
import shutil
import uuid
import warnings
from functools import cache, partial
from pathlib import Path

import numpy as np
import pytest
import sympy as sp
from hypothesis import given, settings
from hypothesis import strategies as st

import vnhc_gym.mechanics._fleet as fleet_template
import vnhc_gym.mechanics._system_template as template
from vnhc_gym.mechanics import (
    FEEDBACK_MODES,
    FLAG_NONFINITE,
    FLAG_SINGULAR,
    ConstrainedSystem,
    MechanicalSystem,
    VelocityConstraint,
    codegen,
)
from vnhc_gym.mechanics import cache as cache_module
from vnhc_gym.mechanics import model as model_module
from vnhc_gym.mechanics.cache import LAYOUT_VERSION, CacheWarning, cache_dir, load_module
from vnhc_gym.mechanics.codegen import CORE_SOURCES, module_key, recipe_parts, sources_digest
from vnhc_gym.mechanics.model import KERNELS
from vnhc_gym.mechanics.numerics import SINCOS_MAX_ARG, pcos, psin, psincos
from vnhc_gym.systems import CURRENTS, flocking_system, make_flocking, make_usv, usv_system

INF = np.full(1, np.inf)

# --------------------------------------------------------------------------- the template on its placeholder


def test_template_defines_every_kernel_a_model_needs() -> None:
    missing = [name for name in KERNELS if not hasattr(template, name)]
    assert not missing
    for name in ("rk4_row", "law_row", "work", "_accel", "_accel_at", "_phi_at", "_aux_at"):
        assert callable(getattr(template, name)), name
    assert (template.NAME, template.N, template.M, template.NP, template.NG, template.BLOCK) == \
           ("placeholder", 1, 1, 1, 1, 1)
    assert template.PARAM_NAMES == ("mass",) and template.OUTPUT_NAMES == ("position",)
    assert (template.OPEN, template.CONTINUOUS, template.SAMPLED) == tuple(FEEDBACK_MODES[m] for m in
                                                                          ("open", "continuous", "sampled"))


def _place_rk4(mode: str, s: np.ndarray, mass: float, told: float, gain: float, dt: float, substeps: int = 1,
               held: float = 0.0, bounds: tuple[float, float] = (-np.inf, np.inf)):
    b = len(s)
    out, u_out, flags = np.empty_like(s), np.empty((b, 1)), np.empty(b, np.int64)
    template.rk4(s, np.full((b, 1), mass), np.full((b, 1), told), np.full((b, 1), held), np.full((b, 1), gain),
                 FEEDBACK_MODES[mode], np.full(1, bounds[0]), np.full(1, bounds[1]), dt, substeps, 1e-10, out, u_out,
                 flags)
    return out, u_out[:, 0], flags


def test_template_continuous_step_is_exact_rk4_of_the_decay() -> None:
    """Point mass p, law told mass pl: u* = -k pl qd, so qd' = -a qd with a = k pl / p, linear: an RK4
    step of length h is exactly qd -> R(-a h) qd, x -> x + h P(-a h) qd (R, P: RK4's polynomials)."""
    s = np.array([[0.5, 2.0], [-1.0, -0.3]])
    mass, told, k, dt, substeps = 2.0, 3.0, 1.5, 0.1, 2
    out, u_out, flags = _place_rk4("continuous", s, mass, told, k, dt, substeps)
    z = -k * told / mass * dt / substeps
    r = 1 + z + z**2 / 2 + z**3 / 6 + z**4 / 24
    p = 1 + z / 2 + z**2 / 6 + z**3 / 24
    h = dt / substeps
    np.testing.assert_allclose(out[:, 1], r**2 * s[:, 1], rtol=1e-14)
    np.testing.assert_allclose(out[:, 0], s[:, 0] + h * p * (1 + r) * s[:, 1], rtol=1e-14)
    np.testing.assert_allclose(u_out, -k * told * s[:, 1] * (1 + r) / 2, rtol=1e-14)
    assert not flags.any()


def test_template_held_controls_are_exact_quadratics() -> None:
    """Constant force: RK4 integrates the quadratic motion exactly."""
    s = np.array([[0.5, 2.0], [-1.0, -0.3]])
    mass, told, k, dt = 2.0, 3.0, 1.5, 0.2

    def quadratic(u: np.ndarray) -> np.ndarray:
        return np.column_stack([s[:, 0] + s[:, 1] * dt + 0.5 * u / mass * dt**2, s[:, 1] + u / mass * dt])

    # sampled: u*(start) + held, then held for the period.
    out, u_out, _ = _place_rk4("sampled", s, mass, told, k, dt, substeps=3, held=0.25)
    u = -k * told * s[:, 1] + 0.25
    np.testing.assert_allclose(out, quadratic(u), rtol=1e-14)
    np.testing.assert_allclose(u_out, u, rtol=1e-14)
    # open: the held control only, clipped.
    out, u_out, _ = _place_rk4("open", s, mass, told, k, dt, held=5.0, bounds=(-1.0, 0.7))
    np.testing.assert_allclose(out, quadratic(np.full(2, 0.7)), rtol=1e-14)
    np.testing.assert_array_equal(u_out, [0.7, 0.7])
    # continuous, saturated at every stage (|u*| = k pl |qd| stays above the bound): constant force too.
    out, u_out, _ = _place_rk4("continuous", s[:1], mass, told, k, dt, bounds=(-0.1, 0.1))
    np.testing.assert_allclose(out, quadratic(np.array([-0.1]))[:1], rtol=1e-14)
    np.testing.assert_array_equal(u_out, [-0.1])


@pytest.mark.parametrize("told", [np.inf, np.nan])
def test_template_singular_law_is_flagged_and_zero(told: float) -> None:
    """C = 1/pl is 0 (pl = inf) or NaN: the law is undefined, flagged, and taken as 0 (only the held force acts)."""
    s = np.array([[0.5, 2.0]])
    for mode in ("continuous", "sampled"):
        out, u_out, flags = _place_rk4(mode, s, 2.0, told, 1.5, 0.1, held=0.4)
        assert flags[0] == FLAG_SINGULAR
        np.testing.assert_allclose(out[0], [0.5 + 2.0 * 0.1 + 0.5 * 0.2 * 0.01, 2.0 + 0.2 * 0.1], rtol=1e-14)
        assert u_out[0] == 0.4
    u, f = np.empty((1, 1)), np.empty(1, np.int64)
    template.law(s, np.full((1, 1), told), np.ones((1, 1)), 1e-10, u, f)
    assert f[0] == FLAG_SINGULAR and u[0, 0] == 0.0
    _, _, flags = _place_rk4("open", np.array([[np.nan, 1.0]]), 2.0, 2.0, 1.0, 0.1)
    assert flags[0] == FLAG_NONFINITE


def test_template_expression_kernels_on_the_point_mass() -> None:
    rng = np.random.default_rng(0)
    s = rng.normal(size=(5, 2))
    p = rng.uniform(0.5, 3, (5, 1))
    out = np.empty((5, 1))
    template.phi(s, p, out)
    np.testing.assert_array_equal(out[:, 0], s[:, 1])  # phi = qd
    template.phi_h(s, p, out)
    np.testing.assert_array_equal(out[:, 0], 0.0)
    template.aux(s, p, out)
    np.testing.assert_array_equal(out[:, 0], s[:, 0])  # the position
    c, g = np.empty((5, 1, 1)), np.empty((5, 1))
    template.cg(s, p, c, g)
    np.testing.assert_allclose(c[:, 0, 0], 1 / p[:, 0], rtol=1e-15)
    np.testing.assert_array_equal(g, 0.0)
    a0, y = np.empty((5, 1)), np.empty((5, 1, 1))
    template.dyn(s, p, a0, y)
    np.testing.assert_array_equal(a0, 0.0)
    np.testing.assert_allclose(y[:, 0, 0], 1 / p[:, 0], rtol=1e-15)
    e = np.empty(5)
    template.energy(s, p, e)
    np.testing.assert_allclose(e, 0.5 * p[:, 0] * s[:, 1] ** 2, rtol=1e-15)
    u, flags = np.empty((5, 1)), np.empty(5, np.int64)
    template.law(s, p, np.full((5, 1), 2.0), 1e-10, u, flags)
    np.testing.assert_allclose(u[:, 0], -2.0 * p[:, 0] * s[:, 1], rtol=1e-15)  # C^-1 (-k qd)
    assert not flags.any()


def test_template_row_kernels_equal_the_batch_kernels() -> None:
    w = template.work()
    n2, m = 2 * template.N, template.M
    assert [a.shape for a in w[:6]] == [(n2,)] * 6 and [a.shape for a in w[6:13]] == [(m,)] * 7
    assert w.C.shape == (m, template.BLOCK)
    for i, a in enumerate(w):  # the scratch vectors do not overlap
        a[...] = i
    assert all(np.all(a == i) for i, a in enumerate(w))
    s = np.array([[0.5, 2.0], [-1.0, -0.3]])
    p, pl, k = np.array([2.0]), np.array([3.0]), np.array([1.5])
    out_b, u_b, flags_b = _place_rk4("continuous", s, 2.0, 3.0, 1.5, 0.1, 2)
    for r in range(2):
        out, u_out = np.empty(2), np.empty(1)
        flag = template.rk4_row(s[r], p, pl, np.zeros(1), k, template.CONTINUOUS, -INF, INF, 0.1, 2, 1e-10, out,
                                u_out, w)
        np.testing.assert_array_equal(out, out_b[r])
        assert u_out[0] == u_b[r] and flag == flags_b[r]
        u = np.empty(1)
        assert template.law_row(s[r], p, k, 1e-10, w, u) == 0
        assert u[0] == -1.5 * 2.0 * s[r, 1]


def test_fleet_template_on_two_placeholder_masses() -> None:
    """Imported as it is, the fleet template is two point masses (state (x0, x1, v0, v1), one mass)."""
    t = fleet_template
    assert (t.R, t.N, t.M, t.NG, t.NAUX) == (2, 2, 2, 2, 2)
    s = np.array([0.3, -1.2, 2.0, 0.5])
    p = np.array([4.0])
    out = np.empty(2)
    t._phi(s, p, out)
    np.testing.assert_array_equal(out, [2.0, 0.5])
    t._aux(s, p, out)
    np.testing.assert_array_equal(out, [0.3, -1.2])
    ds = np.zeros(4)
    t._accel(s, p, np.array([1.0, -2.0]), ds)
    np.testing.assert_array_equal(ds, [0.0, 0.0, 0.25, -0.5])
    c, g = np.empty((2, 1)), np.empty(2)
    t._cg(s, p, c, g)
    np.testing.assert_array_equal(c[:, 0], [0.25, 0.25])
    a0, y = np.empty(2), np.empty((2, 2))
    t._dyn(s, p, a0, y)
    np.testing.assert_array_equal(y, [[0.25, 0.0], [0.0, 0.25]])  # copy b's control moves copy b only
    assert t._energy(s, p) == 0.5 * 4.0 * (2.0**2 + 0.5**2)


# --------------------------------------------------------------------------- generated expression functions


def test_powers_in_denominators_are_parenthesised() -> None:
    """Regression: ``a / b**2`` was once printed as ``a/b*b``."""
    x, v = sp.symbols("x v", real=True)
    k = sp.Symbol("k", positive=True)
    system = MechanicalSystem(name="powtest", q=(x,), qd=(v,), mass_matrix=sp.Matrix([[1]]),
                              control_forces=sp.Matrix([1]), params={k: 2.0})
    # phi chosen so that C, G and phi contain x / (1 + x^2)^2 and x^3 / k^4 terms.
    phi = sp.Matrix([v * x / (1 + x**2) ** 2 + x**3 / k**4 - v / k**3])
    model = ConstrainedSystem(system, VelocityConstraint(phi))
    rng = np.random.default_rng(0)
    f_phi = sp.lambdify([x, v, k], phi[0])
    for _ in range(20):
        s = rng.normal(size=2) * 2
        np.testing.assert_allclose(model.phi(s)[0], f_phi(s[0], s[1], 2.0), rtol=1e-13)
        c, g = model.decoupling(s)
        dphi_dv = sp.diff(phi[0], v).subs({x: s[0], v: s[1], k: 2.0})
        dphi_dx = sp.diff(phi[0], x).subs({x: s[0], v: s[1], k: 2.0})
        np.testing.assert_allclose(c[0, 0], float(dphi_dv), rtol=1e-12)
        np.testing.assert_allclose(g[0], float(dphi_dx) * s[1], rtol=1e-12)


@cache
def coupled() -> ConstrainedSystem:
    """Two masses, one pushed alone and one pushing both: C is a full 2x2 matrix (hand-derived below)."""
    x, y, xd, yd = sp.symbols("x y xd yd", real=True)
    m1, m2, k = sp.symbols("m1 m2 k", positive=True)
    system = MechanicalSystem(name="test_coupled", q=(x, y), qd=(xd, yd), mass_matrix=sp.diag(m1, m2),
                              control_forces=sp.Matrix([[1, 0], [1, 1]]), potential=k * x**2 / 2,
                              params={m1: 1.0, m2: 2.0, k: 3.0})
    return ConstrainedSystem(system, VelocityConstraint(sp.Matrix([xd + y, yd])), outputs={"r2": x**2 + y**2})


def test_full_decoupling_matrix_by_hand() -> None:
    """Y = M^-1 F = [[1/m1, 0], [1/m2, 1/m2]], a0 = (-k x/m1, 0); phi = (xd + y, yd) gives C = Y and
    G = (yd - k x/m1, 0)."""
    model = coupled()
    assert model.compiled.BLOCK == 2 and (model.n, model.m) == (2, 2)
    rng = np.random.default_rng(5)
    s = rng.normal(size=(6, 4))
    p = rng.uniform(0.5, 3, (6, 3))
    m1, m2, k = p.T
    x, y, xd, yd = s.T
    c, g = model.decoupling(s, p)
    want = np.zeros((6, 2, 2))
    want[:, 0, 0], want[:, 1, 0], want[:, 1, 1] = 1 / m1, 1 / m2, 1 / m2
    np.testing.assert_allclose(c, want, rtol=1e-15)
    np.testing.assert_allclose(g, np.column_stack([yd - k * x / m1, 0 * x]), rtol=1e-14, atol=1e-15)
    u = model.control(s, gains=[2.0, 0.5], params=p)
    np.testing.assert_allclose(np.einsum("bij,bj->bi", want, u),
                               -np.array([2.0, 0.5]) * np.column_stack([xd + y, yd]) - g, rtol=1e-12, atol=1e-13)
    np.testing.assert_allclose(model.outputs(s, p)[:, 0], x**2 + y**2, rtol=1e-15)


@pytest.mark.parametrize("which", ["coupled", "usv"])
def test_indexed_functions_equal_the_plain_ones(which: str) -> None:
    """``_accel_at``, ``_phi_at``, ``_aux_at`` read a unit scattered through bigger arrays (how a fleet
    calls its unit): same bits as the plain functions on the gathered unit, nothing else written."""
    model = coupled() if which == "coupled" else make_usv("vortex")
    k = model.compiled
    n, m, npar, naux = model.n, model.m, len(model.param_names), len(model.output_names)
    rng = np.random.default_rng(9)
    s_unit = rng.normal(size=2 * n)
    p_unit = model.default_params * rng.uniform(0.8, 1.2, npar)
    u_unit = rng.normal(size=m)
    si = rng.permutation(3 * 2 * n)[:2 * n].astype(np.int64)
    pi = rng.permutation(2 * npar + 1)[:npar].astype(np.int64)
    ui = rng.permutation(2 * m + 3)[:m].astype(np.int64)
    oi = rng.permutation(2 * max(m, naux) + 3)[:max(m, naux)].astype(np.int64)
    s_big, p_big, u_big = rng.normal(size=6 * n), rng.normal(size=2 * npar + 1), rng.normal(size=2 * m + 3)
    s_big[si], p_big[pi], u_big[ui] = s_unit, p_unit, u_unit

    ds, ds_big = np.zeros(2 * n), np.full(6 * n, 7.0)
    k._accel(s_unit, p_unit, u_unit, ds)
    k._accel_at(s_big, p_big, u_big, ds_big, si, pi, ui)
    np.testing.assert_array_equal(ds_big[si[n:]], ds[n:])
    assert np.all(np.delete(ds_big, si[n:]) == 7.0)
    for plain, indexed, size, method in ((k._phi, k._phi_at, m, model.phi), (k._aux, k._aux_at, naux, model.outputs)):
        out, out_big = np.empty(size), np.full(oi.size + 10, 7.0)
        plain(s_unit, p_unit, out)
        indexed(s_big, p_big, out_big, si, pi, oi)
        np.testing.assert_array_equal(out_big[oi[:size]], out)
        assert np.all(np.delete(out_big, oi[:size]) == 7.0)
        np.testing.assert_array_equal(method(s_unit, p_unit), out)  # what the checked method gives
    np.testing.assert_allclose(model.acceleration(s_unit, u_unit, p_unit), ds[n:], rtol=1e-15)


@pytest.mark.parametrize("name", sorted(CURRENTS))
def test_usv_current_outputs_match_the_current_library(name: str) -> None:
    """The compiled current (and Jacobian) at the boat equals the library's numpy evaluation."""
    model = make_usv(name)
    field = CURRENTS[name]
    params = {k[2:]: v for k, v in zip(model.param_names, model.default_params, strict=True) if k.startswith("c_")}
    rng = np.random.default_rng(1)
    states = rng.normal(size=(16, 6)) * 3
    out = model.outputs(states)
    # Independent Jacobian: central differences of the library's value().
    h = 1e-6
    for row, s in zip(out, states, strict=True):
        c = field.value(s[0], s[1], params)
        jx = (field.value(s[0] + h, s[1], params) - field.value(s[0] - h, s[1], params)) / (2 * h)
        jy = (field.value(s[0], s[1] + h, params) - field.value(s[0], s[1] - h, params)) / (2 * h)
        np.testing.assert_allclose(row[:2], c, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(row[2:], [jx[0], jy[0], jx[1], jy[1]], rtol=1e-6, atol=1e-7)


def test_generated_trig_is_the_inline_polynomial() -> None:
    """Every sine and cosine of a generated module is psin/pcos: the same bits on every machine."""
    text = Path(make_usv("vortex").compiled.__file__).read_text(encoding="utf-8")
    assert "psin(" in text and "pcos(" in text
    assert "math.sin(" not in text and "math.cos(" not in text
    assert text.startswith("# vnhc_gym generated module; sha256 of the rest: ")
    assert "# Generated by vnhc_gym from _system_template.py" in text.splitlines()[1]


@pytest.mark.parametrize("system", ["flocking", "usv-random", "usv-vortex"])
def test_open_loop_rk4_matches_numpy_rk4(system: str) -> None:
    """The open-loop step is the textbook RK4 of qdd = a0 + Y clip(u), here computed in numpy from the
    separately generated ``dynamics`` kernel, with the control held over ``substeps`` steps and its
    mean reported."""
    model = make_flocking(4) if system == "flocking" else make_usv(system.split("-")[1])
    rng = np.random.default_rng(3)
    b, n, m = 64, model.n, model.m
    s0 = rng.normal(size=(b, 2 * n))
    u = rng.normal(scale=80.0, size=(b, m))
    lo, hi = np.full(m, -50.0), np.full(m, 60.0)
    uc = np.clip(u, lo, hi)

    def f(s: np.ndarray) -> np.ndarray:
        return np.concatenate([s[:, n:], model.acceleration(s, uc)], axis=1)

    for substeps in (1, 3):
        dt = 0.05
        h = dt / substeps
        x = s0.copy()
        for _ in range(substeps):
            k1 = f(x)
            k2 = f(x + 0.5 * h * k1)
            k3 = f(x + 0.5 * h * k2)
            k4 = f(x + h * k3)
            x = x + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        out, u_applied, flags = model.step(s0, dt, u=u, u_bounds=(lo, hi), substeps=substeps)
        np.testing.assert_allclose(out, x, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(u_applied, uc, rtol=1e-15)
        assert not flags.any()
    bad = s0.copy()
    bad[5, 0] = np.nan
    _, _, flags = model.step(bad, 0.05, u=u)
    assert flags[5] == FLAG_NONFINITE and not np.delete(flags, 5).any()


@pytest.mark.parametrize("system", ["flocking", "usv-random"])
@pytest.mark.parametrize("feedback", ["open", "continuous", "sampled"])
def test_a_row_gets_what_it_gets_alone(system: str, feedback: str) -> None:
    """A row's step does not depend on its neighbours or its place in the batch, to the bit."""
    model = make_flocking(4) if system == "flocking" else make_usv(system.split("-")[1])
    k = model.compiled
    rng = np.random.default_rng(11)
    b, n, m = 13, model.n, model.m
    s = rng.normal(size=(b, 2 * n))
    if system == "flocking":
        s[:, 15] = s[:, 11] - rng.uniform(1, 3, b)  # C regular
    p = np.tile(model.params(), (b, 1)) * (1.0 + 0.1 * rng.uniform(size=(b, len(model.param_names))))
    pl = p[::-1].copy()  # the told model differs from the true one
    u = rng.normal(scale=5.0, size=(b, m))
    gains = rng.uniform(0.5, 2, (b, m))
    lo, hi = np.full(m, -np.inf), np.full(m, np.inf)
    mode = FEEDBACK_MODES[feedback]

    def run(rows: slice | list[int]):
        out, u_out, flags = np.empty((len(s[rows]), 2 * n)), np.empty((len(s[rows]), m)), np.empty(len(s[rows]),
                                                                                                   np.int64)
        k.rk4(s[rows], p[rows], pl[rows], u[rows], gains[rows], mode, lo, hi, 0.05, 2, 1e-10, out, u_out, flags)
        return out, u_out, flags

    whole = run(slice(None))
    for i in (0, 1, 6, b - 1):
        alone = run([i])
        for a, w in zip(alone, whole, strict=True):
            np.testing.assert_array_equal(a[0], w[i])


@settings(max_examples=300, deadline=None)
@given(st.one_of(st.floats(-SINCOS_MAX_ARG, SINCOS_MAX_ARG, allow_nan=False),
                 st.integers(-600_000, 600_000).map(lambda k: k * math.pi / 2),  # near the quadrant edges
                 st.floats(-1.0, 1.0, allow_nan=False)))
def test_inline_sin_cos_match_libm(x: float) -> None:
    """The generated code's psin/pcos (inline polynomials, so that row loops vectorise) are libm's
    sin/cos to within 2 ulp of 1 (absolute) on the documented range, and to 1 ulp near 0."""
    s, c = float(psin(x)), float(pcos(x))
    assert psincos(x) == (s, c)
    assert abs(s - math.sin(x)) <= 2.3e-16 and abs(c - math.cos(x)) <= 2.3e-16
    if abs(x) < 0.7:
        assert abs(s - math.sin(x)) <= math.ulp(math.sin(x)) and abs(c - math.cos(x)) <= math.ulp(math.cos(x))


@pytest.mark.parametrize("x", [math.inf, -math.inf, math.nan])
def test_inline_sin_cos_of_non_finite_are_nan(x: float) -> None:
    assert math.isnan(psin(x)) and math.isnan(pcos(x))


# --------------------------------------------------------------------------- cache keys


def test_module_key_depends_on_parts_version_and_source_text(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    a, b = tmp_path / "a.py", tmp_path / "b.py"
    a.write_text("X = 1\n")
    b.write_text("Y = 2\n")
    parts = recipe_parts(("flocking", 4))
    base = module_key(parts, [a, b])
    assert module_key(parts, [a, b]) == base and len(base) == 24
    assert module_key(recipe_parts(("flocking", 5)), [a, b]) != base
    assert module_key(recipe_parts(("flocking", "4")), [a, b]) != base
    assert module_key(parts, [a]) != base
    # Names and text enter the hash, not folders: the same files elsewhere give the same key.
    other = tmp_path / "elsewhere"
    other.mkdir()
    shutil.copy(a, other / "a.py")
    shutil.copy(b, other / "b.py")
    assert module_key(parts, [other / "a.py", other / "b.py"]) == base
    shutil.copy(b, other / "c.py")
    assert module_key(parts, [other / "a.py", other / "c.py"]) != base
    assert sources_digest([a, b]) != sources_digest([b, a])
    b.write_text("Y = 3\n")
    assert module_key(parts, [a, b]) != base
    b.write_text("Y = 2\n")
    monkeypatch.setattr(codegen, "CODEGEN_VERSION", codegen.CODEGEN_VERSION + "x")
    assert module_key(parts, [a, b]) != base


def test_recipe_items_are_checked() -> None:
    assert recipe_parts(("usv", "random", 1, 0.5, True)) == ["recipe", repr(("usv", "random", 1, 0.5, True))]
    with pytest.raises(TypeError, match="recipe items"):
        recipe_parts(("flocking", np.int64(4)))
    with pytest.raises(TypeError, match="non-empty tuple"):
        recipe_parts(())
    with pytest.raises(TypeError, match="non-empty tuple"):
        recipe_parts(["flocking", 4])  # type: ignore[arg-type]


def test_core_sources_are_the_files_that_shape_every_module() -> None:
    assert {p.name for p in CORE_SOURCES} == {"codegen.py", "_system_template.py", "numerics.py", "system.py",
                                              "constraint.py"}
    assert all(p.is_file() and p.parent == Path(codegen.__file__).parent for p in CORE_SOURCES)


def _spring(k: float, name: str = "recipe_spring") -> tuple[MechanicalSystem, VelocityConstraint, dict]:
    """x'' = -k x + u, phi = xd + x; records each call so tests can see when the builder runs."""
    _BUILDS.append(k)
    x, xd = sp.symbols("x xd", real=True)
    kk = sp.Symbol("k", positive=True)
    system = MechanicalSystem(name=name, q=(x,), qd=(xd,), mass_matrix=sp.Matrix([[1]]),
                              control_forces=sp.Matrix([[1]]), potential=kk * x**2 / 2, params={kk: k})
    return system, VelocityConstraint(sp.Matrix([xd + x])), {"x2": x**2}


_BUILDS: list[float] = []


def test_user_built_model_key_follows_the_core_sources(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A model built from sympy objects is keyed on them and on the core's text: editing a core file
    gives it a new module (no stale kernels after an upgrade)."""
    keys: list[str] = []

    def record(key: str, make_source, **kwargs):  # stands in for the cache: nothing is generated
        keys.append(key)
        return template

    monkeypatch.setattr(model_module, "load_module", record)
    system, constraint, _ = _spring(2.0)
    ConstrainedSystem(system, constraint)
    ConstrainedSystem(*_spring(2.0)[:2])
    assert keys[0] == keys[1]
    ConstrainedSystem(*_spring(2.0, name="recipe_spring_2")[:2])
    assert keys[2] != keys[0]
    copies = []
    for path in CORE_SOURCES:
        shutil.copy(path, tmp_path / path.name)
        copies.append(tmp_path / path.name)
    monkeypatch.setattr(codegen, "CORE_SOURCES", tuple(copies))
    ConstrainedSystem(system, constraint)
    assert keys[3] == keys[0]  # the same text elsewhere
    for copy in copies:
        text = copy.read_text()
        copy.write_text(text + "\n# an edit\n")
        ConstrainedSystem(system, constraint)
        assert keys[-1] not in keys[:-1], copy.name
        copy.write_text(text)


def test_from_recipe_calls_build_only_on_a_miss_and_regenerates_on_source_edit(tmp_path: Path,
                                                                              monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("VNHC_GYM_CACHE_DIR", str(tmp_path / "cache"))
    src = tmp_path / "spring_source.py"
    src.write_text(f"# version 1 {uuid.uuid4()}\n")
    _BUILDS.clear()
    m1 = ConstrainedSystem.from_recipe(("spring",), partial(_spring, 3.0), sources=[src])
    assert _BUILDS == [3.0]  # miss: built to generate the code
    assert (m1.name, m1.n, m1.m, m1.n_gains, m1.holonomic) == ("recipe_spring", 1, 1, 1, False)
    assert m1.param_names == ("k",) and m1.default_params.tolist() == [3.0] and m1.output_names == ("x2",)
    assert m1.recipe == ("spring",)
    assert Path(m1.compiled.__file__).parent == tmp_path / "cache" / f"layout-{LAYOUT_VERSION}"
    assert len(list((tmp_path / "cache").rglob("vnhc_gen_*.py"))) == 1

    m2 = ConstrainedSystem.from_recipe(("spring",), partial(_spring, 3.0), sources=[src])
    assert _BUILDS == [3.0]  # hit: nothing built
    assert m2.compiled is m1.compiled
    # Metadata comes from the module: a different builder is not consulted on a hit ...
    m3 = ConstrainedSystem.from_recipe(("spring",), partial(_spring, 5.0, "other"), sources=[src])
    assert m3.default_params.tolist() == [3.0] and _BUILDS == [3.0]
    # ... but is checked against the module once the symbolic side is built.
    with pytest.raises(RuntimeError, match="does not match its cached module"):
        _ = m3.system
    assert m2.system.name == "recipe_spring" and _BUILDS == [3.0, 5.0, 3.0]

    src.write_text("# version 2\n")  # an edit of a source file gives a new key and a new module
    m4 = ConstrainedSystem.from_recipe(("spring",), partial(_spring, 3.0), sources=[src])
    assert _BUILDS == [3.0, 5.0, 3.0, 3.0]
    assert m4.compiled is not m1.compiled
    assert len(list((tmp_path / "cache").rglob("vnhc_gen_*.py"))) == 2

    s = np.array([0.7, -0.2])
    np.testing.assert_allclose(m4.phi(s), [s[1] + s[0]], rtol=1e-15)
    np.testing.assert_allclose(m4.outputs(s), [s[0] ** 2], rtol=1e-15)


def test_recipe_model_pickles_its_recipe_not_sympy_objects(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("VNHC_GYM_CACHE_DIR", str(tmp_path / "cache"))
    src = tmp_path / "spring_source.py"
    src.write_text(f"# pickle {uuid.uuid4()}\n")
    model = ConstrainedSystem.from_recipe(("spring", "pickle"), partial(_spring, 2.0), sources=[src])
    _ = model.symbolic  # build the sympy side: it must not travel
    _BUILDS.clear()
    blob = pickle.dumps(model)
    assert b"sympy" not in blob
    clone = pickle.loads(blob)
    assert _BUILDS == []  # unpickling re-imports the cached module, it does not rebuild
    assert clone.compiled is model.compiled and clone.recipe == model.recipe
    assert clone.system.name == "recipe_spring" and _BUILDS == [2.0]


def test_explicit_model_still_pickles_its_symbolic_input() -> None:
    system, constraint = flocking_system(2)
    model = ConstrainedSystem(system, constraint)
    clone = pickle.loads(pickle.dumps(model))
    assert clone.recipe is None and clone.system.name == "flocking2" and clone.compiled is model.compiled


def test_fleet_model_pickles_without_sympy() -> None:
    model = make_flocking(5)
    _ = model.symbolic
    blob = pickle.dumps(model)
    assert b"sympy" not in blob
    clone = pickle.loads(blob)
    assert clone.compiled is model.compiled and clone.recipe == ("fleet", "flocking5", 4)
    s = np.arange(20.0)
    np.testing.assert_array_equal(clone.phi(s), model.phi(s))


@pytest.mark.parametrize("current", ["northeast", "shear"])
def test_recipe_usv_metadata_matches_the_symbolic_system(current: str) -> None:
    model = make_usv(current)
    system, constraint, outputs = usv_system(current)
    explicit = ConstrainedSystem(system, constraint, outputs=outputs)
    for attr in ("name", "n", "m", "n_gains", "holonomic", "param_names", "output_names"):
        assert getattr(model, attr) == getattr(explicit, attr), attr
    np.testing.assert_array_equal(model.default_params, system.default_param_values())
    overrides = {"m": 3.0, "current_scale": 0.5}
    np.testing.assert_array_equal(model.params(**overrides), system.default_param_values(overrides))
    with pytest.raises(ValueError) as from_meta:
        model.params(mass=1.0)
    with pytest.raises(ValueError) as from_sympy:
        system.default_param_values({"mass": 1.0})
    assert str(from_meta.value) == str(from_sympy.value)


# --------------------------------------------------------------------------- the loader's checks (in this process)


def _source(value: int) -> str:
    return f"VALUE = {value}\n"


@pytest.fixture
def cache_root(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    monkeypatch.setenv("VNHC_GYM_CACHE_DIR", str(tmp_path))
    return tmp_path / f"layout-{LAYOUT_VERSION}"


def _load(key: str, value: int, calls: list[int], required: tuple[str, ...] = ("VALUE",)):
    def make() -> str:
        calls.append(value)
        return _source(value)

    return load_module(key, make, label="test", required=required)


def test_cache_dir_is_the_configured_folder(cache_root: Path) -> None:
    assert cache_dir() == cache_root and cache_root.is_dir()


def test_load_module_writes_a_checksummed_entry_once(cache_root: Path) -> None:
    key, calls = uuid.uuid4().hex[:24], []
    module = _load(key, 1, calls)
    assert module.VALUE == 1 and calls == [1]
    path = cache_root / f"vnhc_gen_{key}.py"
    head, body = path.read_text().split("\n", 1)
    assert head == "# vnhc_gym generated module; sha256 of the rest: " + hashlib.sha256(body.encode()).hexdigest()
    assert body == _source(1)
    assert _load(key, 2, calls) is module and calls == [1]  # loaded once per process
    assert not list(cache_root.glob(".*.tmp"))  # no temporary file left behind


@pytest.mark.parametrize("damage", ["truncated", "empty", "edited", "missing name", "does not import"])
def test_load_module_rebuilds_a_damaged_entry_with_one_warning(cache_root: Path, damage: str) -> None:
    key, calls = uuid.uuid4().hex[:24], []
    _load(key, 1, calls)
    path = cache_root / f"vnhc_gen_{key}.py"
    text = path.read_text()

    def checksummed(body: str) -> str:  # a well-formed entry with another text
        return f"# vnhc_gym generated module; sha256 of the rest: {hashlib.sha256(body.encode()).hexdigest()}\n{body}"

    bad = {"truncated": text[:len(text) // 2], "empty": "", "edited": text.replace("VALUE = 1", "VALUE = 9"),
           "missing name": checksummed("X = 1\n"), "does not import": checksummed("1 / 0\n")}[damage]
    path.write_text(bad)
    cache_module._LOADED.pop(key)  # as a fresh process would
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        module = _load(key, 1, calls)
    assert module.VALUE == 1 and calls == [1, 1]
    assert [w.category for w in caught] == [CacheWarning]
    assert "rebuilding the damaged kernel cache entry" in str(caught[0].message)
    assert path.read_text() == text
