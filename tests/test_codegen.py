"""Generated-code checks against independent evaluations (sympy itself, numpy formulas), and the
recipe-keyed cache that lets a warm start skip sympy entirely."""

from __future__ import annotations

import json
import math
import os
import pickle
import subprocess
import sys
import textwrap
from functools import partial
from pathlib import Path

import numpy as np
import pytest
import sympy as sp
from hypothesis import given, settings
from hypothesis import strategies as st

from vnhc_gym.mechanics import ConstrainedSystem, MechanicalSystem, VelocityConstraint
from vnhc_gym.mechanics._kernels import SINCOS_MAX_ARG, pcos, psin, psincos
from vnhc_gym.mechanics.codegen import CODEGEN_VERSION, cache_dir, recipe_key, sources_digest
from vnhc_gym.mechanics.model import CORE_SOURCES
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


# --------------------------------------------------------------------------- recipe-keyed cache

_WARM_SCRIPT = textwrap.dedent("""
    import json, pickle, sys
    import numpy as np
    from vnhc_gym.systems import make_flocking, make_usv

    out = {}
    f = make_flocking(4)
    u = make_usv("northeast")
    out["phi_flocking"] = f.phi(np.arange(16.0)).tolist()
    out["phi_usv"] = u.phi(np.arange(6.0)).tolist()
    out["sympy_after_phi"] = "sympy" in sys.modules
    blob = pickle.dumps(u)
    out["sympy_in_pickle"] = b"sympy" in blob
    u2 = pickle.loads(blob)
    out["phi_unpickled"] = u2.phi(np.arange(6.0)).tolist()
    out["params"] = u2.params(m=3.0).tolist()
    out["sympy_after_pickle"] = "sympy" in sys.modules
    out["system_name"] = u2.system.name  # lazy: builds the symbolic side now
    out["sympy_after_system"] = "sympy" in sys.modules
    print(json.dumps(out))
""")


def _run_fresh(cache: Path) -> dict:
    env = {**os.environ, "VNHC_GYM_CACHE_DIR": str(cache)}
    proc = subprocess.run([sys.executable, "-c", _WARM_SCRIPT], env=env, capture_output=True, text=True,
                          timeout=600, check=False)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout.strip().splitlines()[-1])


def test_warm_start_does_not_import_sympy(tmp_path: Path) -> None:
    """With a warm cache, making the shipped systems, evaluating and pickling them never imports sympy."""
    cold = _run_fresh(tmp_path)
    assert cold["sympy_after_phi"]  # the first process derived and generated the code
    warm = _run_fresh(tmp_path)
    assert not warm["sympy_after_phi"]
    assert not warm["sympy_in_pickle"]
    assert not warm["sympy_after_pickle"]
    assert warm["sympy_after_system"] and warm["system_name"] == "usv_northeast"
    s = np.arange(16.0)  # flocking: q = s[:8], qd = (xd_1..4, zd_1..4) = s[8:]
    xd, zd = s[8:12], s[12:16]
    np.testing.assert_allclose(warm["phi_flocking"], xd[3] * zd[:3] - xd[:3] * zd[3], rtol=1e-14)
    for run in (cold, warm):
        np.testing.assert_allclose(run["phi_flocking"], warm["phi_flocking"], rtol=0)
        np.testing.assert_allclose(run["phi_usv"], warm["phi_usv"], rtol=0)
        np.testing.assert_allclose(run["phi_unpickled"], warm["phi_usv"], rtol=0)
        assert run["params"] == [3.0, 1.5, 1.0, 1.0, 1.0]


def test_recipe_key_depends_on_recipe_version_and_source_text(tmp_path: Path) -> None:
    a, b = tmp_path / "a.py", tmp_path / "b.py"
    a.write_text("X = 1\n")
    b.write_text("Y = 2\n")
    base = recipe_key(("flocking", 4), sources_digest([a, b]))
    assert recipe_key(("flocking", 4), sources_digest([a, b])) == base
    assert recipe_key(("flocking", 5), sources_digest([a, b])) != base
    assert recipe_key(("flocking", "4"), sources_digest([a, b])) != base
    assert recipe_key(("flocking", 4), sources_digest([a])) != base
    b.write_text("Y = 3\n")
    assert recipe_key(("flocking", 4), sources_digest([a, b])) != base
    # The version enters the cache folder (and the hash load_module names the module by).
    assert cache_dir().name == f"codegen-v{CODEGEN_VERSION}"
    with pytest.raises(TypeError, match="recipe items"):
        recipe_key(("flocking", np.int64(4)), "digest")
    with pytest.raises(TypeError, match="non-empty tuple"):
        recipe_key([], "digest")  # type: ignore[arg-type]


def test_shipped_recipes_hash_the_files_that_define_them() -> None:
    names = {p.name for p in CORE_SOURCES}
    assert names == {"system.py", "constraint.py", "codegen.py"}
    assert all(p.is_file() for p in CORE_SOURCES)


_BUILDS: list[float] = []


def _spring(k: float, name: str = "recipe_spring") -> tuple[MechanicalSystem, VelocityConstraint, dict]:
    """x'' = -k x + u, phi = xd + x; records each call so tests can see when the builder runs."""
    _BUILDS.append(k)
    x, xd = sp.symbols("x xd", real=True)
    kk = sp.Symbol("k", positive=True)
    system = MechanicalSystem(name=name, q=(x,), qd=(xd,), mass_matrix=sp.Matrix([[1]]),
                              control_forces=sp.Matrix([[1]]), potential=kk * x**2 / 2, params={kk: k})
    return system, VelocityConstraint(sp.Matrix([xd + x])), {"x2": x**2}


def test_from_recipe_calls_build_only_on_a_miss_and_regenerates_on_source_edit(tmp_path: Path,
                                                                              monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("VNHC_GYM_CACHE_DIR", str(tmp_path / "cache"))
    src = tmp_path / "spring_source.py"
    src.write_text("# version 1\n")
    _BUILDS.clear()
    m1 = ConstrainedSystem.from_recipe(("spring",), partial(_spring, 3.0), sources=[src])
    assert _BUILDS == [3.0]  # miss: built to generate the code
    assert (m1.name, m1.n, m1.m, m1.n_gains, m1.holonomic) == ("recipe_spring", 1, 1, 1, False)
    assert m1.param_names == ("k",) and m1.default_params.tolist() == [3.0] and m1.output_names == ("x2",)
    assert m1.recipe == ("spring",)
    generated = sorted((tmp_path / "cache").rglob("vnhc_gen_*.py"))
    assert len(generated) == 1

    m2 = ConstrainedSystem.from_recipe(("spring",), partial(_spring, 3.0), sources=[src])
    assert _BUILDS == [3.0]  # hit: nothing built
    assert m2.kernels is m1.kernels
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
    assert m4.kernels is not m1.kernels
    assert len(sorted((tmp_path / "cache").rglob("vnhc_gen_*.py"))) == 2

    s = np.array([0.7, -0.2])
    np.testing.assert_allclose(m4.phi(s), [s[1] + s[0]], rtol=1e-15)
    np.testing.assert_allclose(m4.outputs(s), [s[0] ** 2], rtol=1e-15)
    # u* = -(k phi + G), G = d(xd + x)/dt at u = 0 = -k x + xd (C = 1)
    np.testing.assert_allclose(m4.control(s, gains=2.0), [-(2.0 * (s[1] + s[0]) + (-3.0 * s[0] + s[1]))],
                               rtol=1e-14)


def test_recipe_model_pickles_its_recipe_not_sympy_objects(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("VNHC_GYM_CACHE_DIR", str(tmp_path / "cache"))
    src = tmp_path / "spring_source.py"
    src.write_text("# pickle\n")
    model = ConstrainedSystem.from_recipe(("spring", "pickle"), partial(_spring, 2.0), sources=[src])
    _ = model.symbolic  # build the sympy side: it must not travel
    _BUILDS.clear()
    blob = pickle.dumps(model)
    assert b"sympy" not in blob
    clone = pickle.loads(blob)
    assert _BUILDS == []  # unpickling re-imports the cached module, it does not rebuild
    assert clone.kernels is model.kernels and clone.recipe == model.recipe
    np.testing.assert_array_equal(clone.phi(np.array([1.0, 2.0])), model.phi(np.array([1.0, 2.0])))
    assert clone.system.name == "recipe_spring" and _BUILDS == [2.0]


def test_explicit_model_still_pickles_its_symbolic_input() -> None:
    system, constraint = flocking_system(2)
    model = ConstrainedSystem(system, constraint)
    clone = pickle.loads(pickle.dumps(model))
    assert clone.recipe is None and clone.system.name == "flocking2" and clone.kernels is model.kernels


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


def test_recipe_flocking_matches_explicit_model_and_hand_formulas() -> None:
    n = 4
    model = make_flocking(n)
    explicit = ConstrainedSystem(*flocking_system(n))
    assert model.kernels is not explicit.kernels  # two independent code paths and cache keys
    for attr in ("name", "n", "m", "n_gains", "holonomic", "param_names", "output_names"):
        assert getattr(model, attr) == getattr(explicit, attr), attr
    np.testing.assert_array_equal(model.default_params, explicit.default_params)
    rng = np.random.default_rng(7)
    states = rng.normal(size=(32, 4 * n))
    params = np.column_stack([rng.uniform(1, 3, size=(32, n)), rng.uniform(5, 15, size=32)])
    gains = rng.uniform(0.1, 3.0, size=(32, n - 1))
    xd, zd = states[:, 2 * n:3 * n], states[:, 3 * n:]
    masses, g = params[:, :n], params[:, n]
    phi_hand = xd[:, -1:] * zd[:, :-1] - xd[:, :-1] * zd[:, -1:]
    np.testing.assert_allclose(model.phi(states, params), phi_hand, rtol=1e-13, atol=1e-14)
    np.testing.assert_array_equal(model.phi(states, params), explicit.phi(states, params))
    # C = diag((xd_N - zd_N) / m_b), G_b = g (xd_b - xd_N); u* = C^-1 (-K phi - G).
    c_hand = (xd[:, -1:] - zd[:, -1:]) / masses[:, :-1]
    g_hand = g[:, None] * (xd[:, :-1] - xd[:, -1:])
    u_hand = (-gains * phi_hand - g_hand) / c_hand
    np.testing.assert_allclose(model.control(states, gains, params), u_hand, rtol=1e-10, atol=1e-12)
    np.testing.assert_array_equal(model.control(states, gains, params), explicit.control(states, gains, params))


@pytest.mark.parametrize("system", ["flocking", "usv-random", "usv-vortex"])
def test_open_loop_scalar_rk4_matches_numpy_rk4(system: str) -> None:
    """The open-loop step is generated as scalar code (no work arrays); it must be the textbook
    RK4 of qdd = a0 + Y clip(u), here computed in numpy from the separately generated
    ``dynamics`` kernel, with the control held over ``substeps`` steps and its mean reported."""
    from vnhc_gym.systems.flocking import make_flocking
    from vnhc_gym.systems.usv import make_usv

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
    assert flags[5] != 0 and not np.delete(flags, 5).any()


@pytest.mark.parametrize("system", ["flocking", "usv-random"])
def test_row_blocks_give_each_row_what_it_gets_alone(system: str) -> None:
    """The open-loop RK4 and the phi/aux pass run rows in SIMD blocks of ``LANES`` plus a scalar
    remainder: a row's result must not depend on its neighbours or its place, to the bit, and the
    step's phi/aux must be what the separate ``phi``/``aux`` kernels give at the new state."""
    from vnhc_gym.mechanics import FEEDBACK_MODES
    from vnhc_gym.mechanics.codegen import LANES

    model = make_flocking(4) if system == "flocking" else make_usv(system.split("-")[1])
    k = model.kernels
    rng = np.random.default_rng(11)
    b, n, m = 2 * LANES + 5, model.n, model.m
    s0 = rng.normal(size=(b, 2 * n))
    p = np.tile(model.params(), (b, 1))
    p[:, :] *= 1.0 + 0.1 * rng.uniform(size=p.shape)  # a different model per row
    u = rng.normal(scale=20.0, size=(b, m))
    whole, u_whole, _ = model.step(s0, 0.05, u=u, params=p, substeps=2)
    for i in (0, 1, LANES - 1, LANES, 2 * LANES, b - 1):
        alone, u_alone, _ = model.step(s0[i:i + 1], 0.05, u=u[i:i + 1], params=p[i:i + 1], substeps=2)
        np.testing.assert_array_equal(whole[i], alone[0])
        np.testing.assert_array_equal(u_whole[i], u_alone[0])

    s = s0.copy()
    pa = p[::-1].copy()  # the told model differs from the true one
    lo, hi = np.full(m, -np.inf), np.full(m, np.inf)
    nxt, u_out, flags = np.empty_like(s), np.empty((b, m)), np.zeros(b, np.int64)
    phi, aux = np.empty((b, m)), np.empty((b, k.NAUX))
    k.advance(s, p, u, np.zeros((b, k.NG)), FEEDBACK_MODES["open"], lo, hi, 0.05, 1, 1e-12, nxt, u_out, flags,
              np.zeros((b, n)), phi, pa, aux)
    want_phi, want_aux = np.empty_like(phi), np.empty_like(aux)
    k.phi(s, p, want_phi)
    k.aux(s, pa, want_aux)
    np.testing.assert_array_equal(phi, want_phi)
    np.testing.assert_array_equal(aux, want_aux)


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
