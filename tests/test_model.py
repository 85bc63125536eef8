"""`ConstrainedSystem`, the checked numpy face of the core, against independent evaluations: sympy
itself, formulas typed by hand, numpy's RK4 and the current library; a row's result does not
depend on its batch; models pickle without their sympy objects."""

from __future__ import annotations

import pickle
from functools import cache

import numpy as np
import pytest
import sympy as sp

from vnhc_gym.mechanics import FLAG_NONFINITE, ConstrainedSystem, MechanicalSystem, VelocityConstraint
from vnhc_gym.systems import CURRENTS, flocking_system, make_flocking, make_usv, usv_system


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
    assert (model.n, model.m) == (2, 2)
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


@pytest.mark.parametrize("name", sorted(CURRENTS))
def test_usv_current_outputs_match_the_current_library(name: str) -> None:
    """The current (and Jacobian) at the boat equals the library's numpy evaluation."""
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


@pytest.mark.parametrize("system", ["flocking", "usv-random", "usv-vortex"])
def test_open_loop_rk4_matches_numpy_rk4(system: str) -> None:
    """The open-loop step is the textbook RK4 of qdd = a0 + Y clip(u), here computed in numpy from the
    model's ``dynamics``, with the control held over ``substeps`` steps and its
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
    rng = np.random.default_rng(11)
    b, n, m = 13, model.n, model.m
    s = rng.normal(size=(b, 2 * n))
    if system == "flocking":
        s[:, 15] = s[:, 11] - rng.uniform(1, 3, b)  # C regular
    p = np.tile(model.params(), (b, 1)) * (1.0 + 0.1 * rng.uniform(size=(b, len(model.param_names))))
    u = rng.normal(scale=5.0, size=(b, m))
    gains = rng.uniform(0.5, 2, (b, m))

    def run(rows: slice | list[int]) -> tuple[np.ndarray, ...]:
        return model.step(s[rows], 0.05, u=u[rows], feedback=feedback, gains=gains[rows], params=p[rows], substeps=2)

    whole = run(slice(None))
    for i in (0, 1, 6, b - 1):
        alone = run([i])
        for a, w in zip(alone, whole, strict=True):
            np.testing.assert_array_equal(a[0], w[i])


def test_recipe_model_pickles_its_recipe_not_sympy_objects() -> None:
    model = make_usv("northeast")
    _ = model.symbolic  # build the sympy side: it must not travel
    blob = pickle.dumps(model)
    assert b"sympy" not in blob
    clone = pickle.loads(blob)
    assert clone.functions is model.functions and clone.recipe == model.recipe  # the printed module, by name
    s = np.linspace(-1.0, 1.0, 6)
    np.testing.assert_array_equal(clone.phi(s), model.phi(s))


def test_explicit_model_pickles_its_symbolic_input() -> None:
    system, constraint = flocking_system(2)
    model = ConstrainedSystem(system, constraint)
    clone = pickle.loads(pickle.dumps(model))
    assert clone.recipe is None and clone.system.name == "flocking2"
    s = np.linspace(-1.0, 2.0, 8)
    np.testing.assert_allclose(clone.control(s), model.control(s), rtol=1e-15)


def test_fleet_model_pickles_without_sympy() -> None:
    model = make_flocking(5)
    _ = model.symbolic
    blob = pickle.dumps(model)
    assert b"sympy" not in blob
    clone = pickle.loads(blob)
    assert clone.recipe == ("fleet", "flocking5", 4)
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
