"""Turn a :class:`~vnhc_gym.mechanics.constraint.SymbolicLaw` into a cached numba module.

Why code generation: the law and the RK4 step are a few dozen flops per system, so a numpy
implementation is dominated by per-call overhead (about 1 us per array op).  Emitting the
common-subexpression-eliminated formulas as straight-line scalar code and compiling it with
numba gives one fused kernel per batch: microseconds at batch 1, millions of steps per second
in a batch.  The open-loop RK4 step and the batched ``phi`` and extra outputs run over blocks of
``LANES`` rows as a loop over lanes that LLVM turns into SIMD code (see :func:`_open_rows_body`).
The generated file is written once to a cache folder keyed by a hash of the
symbolic input (or, for the shipped systems, of a *recipe* such as ``("flocking", 4)`` plus the
source text of the files that define it, see :func:`recipe_key`), and numba caches its machine
code beside it, so a new process neither re-derives nor recompiles.  Only code generation
imports sympy: loading a cached module does not.
"""

from __future__ import annotations

import hashlib
import importlib.util
import math
import os
import sys
import tempfile
import threading
from collections.abc import Callable, Iterable, Mapping
from functools import cache
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # sympy is imported by the functions that generate code, never on a warm start
    import sympy as sp

    from vnhc_gym.mechanics.constraint import SymbolicLaw

__all__ = ["cache_dir", "generate_source", "load_module", "recipe_key", "sources_digest", "CODEGEN_VERSION"]

CODEGEN_VERSION = "19"
_LOCK = threading.Lock()
_LOADED: dict[str, ModuleType] = {}


def cache_dir() -> Path:
    """Folder for generated modules: ``$VNHC_GYM_CACHE_DIR`` or ``~/.cache/vnhc_gym``."""
    root = os.environ.get("VNHC_GYM_CACHE_DIR")
    base = Path(root) if root else Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "vnhc_gym"
    return base / f"codegen-v{CODEGEN_VERSION}"


def sources_digest(paths: Iterable[str | os.PathLike[str]]) -> str:
    """sha256 over the names and contents of ``paths`` (the files that define a system's symbolic content).

    Part of a recipe's cache key (:func:`recipe_key`): editing any of these files gives a new key,
    so a stale generated module is never reused.  File names, not folders, enter the hash, so the
    key does not depend on where the package is installed.
    """
    h = hashlib.sha256()
    for path in paths:
        data = Path(path).read_bytes()
        h.update(f"{Path(path).name}\x00{len(data)}\x00".encode())
        h.update(data)
    return h.hexdigest()


def recipe_key(recipe: tuple[object, ...], digest: str) -> list[str]:
    """Cache-key parts of a recipe-built system: the recipe (e.g. ``("flocking", 4)``) and a
    :func:`sources_digest`.  :func:`load_module` adds ``CODEGEN_VERSION``.

    Recipe items must be str, int, float or bool (their ``repr`` is stable across processes).
    """
    if not isinstance(recipe, tuple) or not recipe:
        raise TypeError(f"recipe must be a non-empty tuple, got {recipe!r}")
    for item in recipe:
        if type(item) not in (str, int, float, bool):
            raise TypeError(f"recipe items must be str, int, float or bool, got {type(item).__name__} in {recipe!r}")
    return ["recipe", repr(recipe), digest]


@cache
def _printer_class() -> Any:
    """A plain ``math`` printer class; integer powers become products (faster, exact for squares).

    Built on first use so that importing this module does not import sympy."""
    from sympy.printing.pycode import PythonCodePrinter

    class _Printer(PythonCodePrinter):
        def _print_Pow(self, expr: sp.Pow, rational: bool = False) -> str:
            base, exp = expr.args
            if exp.is_Integer and 1 < int(exp) <= 4:
                b = self.parenthesize(base, 100)
                return "(" + "*".join([b] * int(exp)) + ")"  # parenthesised: it may follow a "/"
            if exp.is_Integer and -4 <= int(exp) <= -1:
                b = self.parenthesize(base, 100)
                return "1.0/(" + "*".join([b] * -int(exp)) + ")"
            return super()._print_Pow(expr, rational=rational)

    return _Printer


def _body(assignments: list[tuple[str, sp.Expr]], subs: dict[sp.Symbol, sp.Symbol], reads: str) -> str:
    """Straight-line code for ``target = expr`` pairs with shared subexpressions."""
    import sympy as sp

    printer = _printer_class()({"fully_qualified_modules": True, "standard": "python3"})
    exprs = [sp.sympify(e).xreplace(subs) for _, e in assignments]
    temps, reduced = sp.cse(exprs, symbols=sp.numbered_symbols("t_"), optimizations="basic")
    lines = [reads] if reads else []
    for sym, expr in temps:
        lines.append(f"{sym} = {printer.doprint(sp.Float(expr) if expr.is_Number else expr)}")
    for (target, _), expr in zip(assignments, reduced, strict=True):
        lines.append(f"{target} = {printer.doprint(sp.Float(expr) if expr.is_Number else expr)}")
    if not lines:
        lines = ["pass"]
    return "\n".join("    " + line for line in lines)


def _lane_trig(code: str) -> str:
    """Swap libm's sin/cos for the inline polynomials ``psin``/``pcos`` (``_kernels``) in a lane
    loop: a call stops LLVM from vectorising the loop.  Only the lane kernels use them; the
    per-row kernels (the feedback modes, the law) keep libm, which compiles much faster there."""
    return code.replace("math.sin(", "psin(").replace("math.cos(", "pcos(")


def _used(assignments: list[tuple[str, sp.Expr]], names: list[sp.Symbol]) -> list[int]:
    import sympy as sp

    free: set[sp.Symbol] = set()
    for _, e in assignments:
        free |= sp.sympify(e).free_symbols
    return [i for i, s in enumerate(names) if s in free]


def _reads(indices: list[int], array: str, prefix: str) -> str:
    return "; ".join(f"{prefix}{i} = {array}[{i}]" for i in indices)


def _literal(value: float) -> str:
    """A float as Python source (``repr`` round-trips exactly; inf and nan need a call)."""
    return repr(value) if math.isfinite(value) else f"float({str(value)!r})"


#: Rows per block of the generated lane kernels (``_rows_open``, ``_phi_rows``, ``_aux_rows``).  A block's
#: inputs are copied into one scratch array laid out variable-major with this constant stride, so
#: that LLVM can prove the lanes independent and vectorise the loop over them (about 3x for the
#: USV's RK4 with AVX2).  32 rows x ~40 variables stay in L1.
LANES = 32


def _lane_loads(names: list[str], sources: list[str], first: int) -> tuple[list[str], list[str]]:
    """Gather lines (``buf[slot] = source``, at row ``r``) and lane-loop loads (``name = buf[slot]``)."""
    gather = [f"buf[{(first + k) * LANES} + l] = {src}" for k, src in enumerate(sources)]
    loads = [f"{name} = buf[{(first + k) * LANES} + l]" for k, name in enumerate(names)]
    return gather, loads


def _block_head(n_slots: int, gathers: list[str]) -> list[str]:
    """Opening lines of a lane kernel: the scratch array, the loop over row blocks and the gather
    of a block's inputs (``gathers``, from :func:`_lane_loads`) into it."""
    return [f"buf = np.empty({max(1, n_slots) * LANES})",
            f"for b0 in range(start, stop, {LANES}):",
            f"    nl = min({LANES}, stop - b0)",
            "    for l in range(nl):",
            "        r = b0 + l",
            *(["        " + g for g in gathers] or ["        pass"])]


def _open_rows_body(accel: list[sp.Expr], state_syms: list[sp.Symbol], param_syms: list[sp.Symbol], m: int) -> str:
    """Body of the generated ``_rows_open``: RK4 with a held, clipped control, as scalar code.

    Rows go in blocks of ``LANES``: gather the block's state, parameters and clipped controls
    into ``buf`` (variable-major), run the substeps as a loop over lanes on local variables
    (SIMD), then write the rows out.  Same arithmetic, term for term, as the loop version
    (``x + 0.5 * h * k``, then ``x + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)``) and no
    contraction into FMA, so the results are bit-identical to it and between SIMD and scalar
    lanes, up to sin and cos (``psin``/``pcos`` here, libm there: within 2.3e-16).
    """
    import sympy as sp

    n2 = len(state_syms)
    n = n2 // 2
    subs = {s: sp.Symbol(f"z_{i}") for i, s in enumerate(state_syms)}
    subs.update({s: sp.Symbol(f"p_{i}") for i, s in enumerate(param_syms)})
    stage = _lane_trig(_body([(f"KK_{n + i}", e) for i, e in enumerate(accel)], subs, ""))
    used_p = _used([("", e) for e in accel], param_syms)
    gx, lx = _lane_loads([f"x_{i}" for i in range(n2)], [f"S[r, {i}]" for i in range(n2)], 0)
    gp, lp = _lane_loads([f"p_{i}" for i in used_p], [f"P[r, {i}]" for i in used_p], n2)
    gu, lu = _lane_loads([f"u_{a}" for a in range(m)], [f"min(max(U[r, {a}], lo[{a}]), hi[{a}])" for a in range(m)],
                         n2 + len(used_p))
    lines = _block_head(n2 + len(used_p) + m, gx + gp + gu)
    lines += ["    for _ in range(substeps):",
              "        for l in range(nl):"]
    lines += ["            " + ld for ld in lx + lp + lu]
    lines += [f"            z_{i} = x_{i}" for i in range(n2)]
    for k, (src, coef) in enumerate((("k1", "0.5 * h"), ("k2", "0.5 * h"), ("k3", "h"), ("k4", None)), start=1):
        lines += [f"            k{k}_{i} = z_{n + i}" for i in range(n)]
        lines += ["        " + line.replace("KK_", f"k{k}_") for line in stage.split("\n") if line.strip() != "pass"]
        if coef is not None:
            lines += [f"            z_{i} = x_{i} + {coef} * {src}_{i}" for i in range(n2)]
    lines += [f"            x_{i} = x_{i} + (h / 6.0) * (k1_{i} + 2.0 * k2_{i} + 2.0 * k3_{i} + k4_{i})"
              for i in range(n2)]
    lines += [f"            buf[{i * LANES} + l] = x_{i}" for i in range(n2)]
    lines += ["    for l in range(nl):",
              "        r = b0 + l",
              "        finite = True"]
    for i in range(n2):
        lines += [f"        v = buf[{i * LANES} + l]", f"        out[r, {i}] = v",
                  "        if not math.isfinite(v):", "            finite = False"]
    for a in range(m):
        slot = (n2 + len(used_p) + a) * LANES
        lines += ["        acc = 0.0", "        for _ in range(substeps):", f"            acc += buf[{slot} + l]",
                  f"        u_out[r, {a}] = acc / substeps"]
    lines += ["        flags[r] = 0 if finite else FLAG_NONFINITE"]
    return "\n".join("    " + line for line in lines)


def _lane_rows_body(exprs: list[sp.Expr], state_syms: list[sp.Symbol], param_syms: list[sp.Symbol]) -> str:
    """Body of a generated ``_<name>_rows(start, stop, S, P, out)``: ``out[r, j] = exprs[j](S[r], P[r])``
    for rows ``start:stop``, in blocks of ``LANES`` (gather, a SIMD loop over lanes, scatter)."""
    import sympy as sp

    subs = {s: sp.Symbol(f"s_{i}") for i, s in enumerate(state_syms)}
    subs.update({s: sp.Symbol(f"p_{i}") for i, s in enumerate(param_syms)})
    part = [(f"o_{j}", e) for j, e in enumerate(exprs)]
    used_s = _used(part, state_syms)
    used_p = _used(part, param_syms)
    gs, ls = _lane_loads([f"s_{i}" for i in used_s], [f"S[r, {i}]" for i in used_s], 0)
    gp, lp = _lane_loads([f"p_{i}" for i in used_p], [f"P[r, {i}]" for i in used_p], len(used_s))
    out0 = len(used_s) + len(used_p)
    lines = _block_head(out0 + len(exprs), gs + gp)
    lines += ["    for l in range(nl):"]
    lines += ["        " + ld for ld in ls + lp]
    lines += ["    " + line for line in _lane_trig(_body(part, subs, "")).split("\n") if line.strip() != "pass"]
    lines += [f"        buf[{(out0 + j) * LANES} + l] = o_{j}" for j in range(len(exprs))]
    lines += ["    for l in range(nl):",
              "        r = b0 + l"]
    lines += [f"        out[r, {j}] = buf[{(out0 + j) * LANES} + l]" for j in range(len(exprs))]
    return "\n".join("    " + line for line in lines)


def _listed_rows(body: str) -> str:
    """A lane kernel's body (over rows ``start:stop``) turned into one over the rows listed in
    ``rows[start:stop]``: the same lane code, so the same numbers, row for row."""
    return body.replace("r = b0 + l", "r = rows[b0 + l]")


def generate_source(law: SymbolicLaw, outputs: Mapping[str, sp.Expr] | None = None) -> str:
    """Python source of a numba module implementing ``law`` (see the module template).

    Besides the kernels, the module records what :class:`~vnhc_gym.mechanics.ConstrainedSystem`
    needs to run without sympy: ``NAME``, ``N``, ``M``, ``NG``, ``HOLONOMIC``, ``PARAM_NAMES``,
    ``PARAM_DEFAULTS`` and ``OUTPUT_NAMES``.
    """
    import sympy as sp

    system = law.system
    n, m = system.n, system.m
    state_syms = list(system.q) + list(system.qd)
    param_syms = list(system.param_symbols)
    subs = {s: sp.Symbol(f"s_{i}") for i, s in enumerate(state_syms)}
    subs.update({s: sp.Symbol(f"p_{i}") for i, s in enumerate(param_syms)})
    outputs = outputs or {}

    def block(assignments: list[tuple[str, sp.Expr]]) -> str:
        s_idx = _used(assignments, state_syms)
        p_idx = _used(assignments, param_syms)
        reads = "; ".join(x for x in (_reads(s_idx, "s", "s_"), _reads(p_idx, "p", "p_")) if x)
        return _body(assignments, subs, reads)

    phi_body = block([(f"out[{b}]", law.phi[b]) for b in range(m)])
    hol_body = block([(f"out[{b}]", law.phi_h[b]) for b in range(m)]) if law.phi_h is not None else "    pass"
    dyn = [(f"a0[{i}]", law.a0[i]) for i in range(n)]
    dyn += [(f"Y[{i}, {a}]", law.Y[i, a]) for i in range(n) for a in range(m)]
    cg = [(f"C[{b}, {a}]", law.C[b, a]) for b in range(m) for a in range(m)]
    cg += [(f"G[{b}]", law.G[b]) for b in range(m)]
    # Acceleration a0 + Y u written out with u as symbols: sparsity of Y is used for free.
    u_syms = [sp.Symbol(f"u_{a}") for a in range(m)]
    accel = law.a0 + law.Y * sp.Matrix(u_syms)
    acc_assign = [(f"ds[{n + i}]", accel[i]) for i in range(n)]
    u_reads = "; ".join(f"u_{a} = u[{a}]" for a in range(m) if any(
        sp.Symbol(f"u_{a}") in e.free_symbols for _, e in acc_assign))
    acc_body = block(acc_assign)
    if u_reads:
        acc_body = "    " + u_reads + "\n" + acc_body
    diagonal = all(sp.simplify(law.C[b, a]) == 0 for b in range(m) for a in range(m) if a != b)
    if diagonal:
        solve = ("    flag = 0\n"
                 "    for b in range(M):\n"
                 "        c = C[b, b]\n"
                 "        if not abs(c) > tol * max(1.0, abs(c)):\n"
                 "            flag = FLAG_SINGULAR\n"
                 "    if flag:\n"
                 "        for b in range(M):\n"
                 "            u[b] = 0.0\n"
                 "        return flag\n"
                 "    for b in range(M):\n"
                 "        u[b] = G[b] / C[b, b]\n"
                 "    return 0")
    else:
        solve = "    return solve_small(C, G, u, tol)"
    defaults = ", ".join(_literal(v) for v in system.default_param_values())
    phi_rows = _lane_rows_body(list(law.phi), state_syms, param_syms)
    aux_rows = _lane_rows_body(list(outputs.values()), state_syms, param_syms) if outputs else "    pass"
    return _TEMPLATE.format(
        name=system.name, n=n, m=m, n_params=len(param_syms), n_gains=law.n_gains, n_aux=len(outputs),
        holonomic=law.phi_h is not None, param_names=tuple(str(p) for p in param_syms),
        param_defaults=f"({defaults}{',' if len(param_syms) == 1 else ''})", output_names=tuple(outputs),
        phi_body=phi_body, hol_body=hol_body, dyn_body=block(dyn), cg_body=block(cg),
        energy_body=block([("e", law.energy)]),
        acc_body=acc_body, solve_body=solve, diagonal=diagonal,
        open_body=_open_rows_body(list(accel), state_syms, param_syms, m),
        phi_rows_body=phi_rows, phi_idx_body=_listed_rows(phi_rows),
        aux_rows_body=aux_rows, aux_idx_body=_listed_rows(aux_rows),
    )


def _key(parts: list[str]) -> str:
    digest = hashlib.sha256("\x00".join([CODEGEN_VERSION, *parts]).encode()).hexdigest()
    return digest[:20]


def load_module(key_parts: list[str], make_source: Callable[[], str]) -> ModuleType:
    """Import the generated module for ``key_parts``, generating it first if not cached.

    ``make_source`` is only called on a cache miss, so a warm start skips the symbolic work.
    """
    key = _key(key_parts)
    with _LOCK:
        if key in _LOADED:
            return _LOADED[key]
        folder = cache_dir()
        folder.mkdir(parents=True, exist_ok=True)
        path = folder / f"vnhc_gen_{key}.py"
        if not path.exists():
            source = make_source()
            # Atomic publish: parallel processes (SubprocVecEnv) may race to write the file.
            fd, tmp = tempfile.mkstemp(dir=folder, suffix=".tmp")
            with os.fdopen(fd, "w") as fh:
                fh.write(source)
            os.replace(tmp, path)
        mod_name = f"vnhc_gym._generated_{key}"
        spec = importlib.util.spec_from_file_location(mod_name, path)
        if spec is None or spec.loader is None:  # pragma: no cover - importlib contract
            raise ImportError(f"cannot import generated module {path}")
        module = importlib.util.module_from_spec(spec)
        sys.modules[mod_name] = module  # numba's cache and pickling look modules up by name
        spec.loader.exec_module(module)
        _LOADED[key] = module
        return module


_TEMPLATE = '''\
# Generated by vnhc_gym.mechanics.codegen for system {name!r}. Do not edit: delete to regenerate.
import math

import numpy as np
from numba import njit, prange

from vnhc_gym.mechanics._kernels import FLAG_NONFINITE, FLAG_SINGULAR, pcos, psin, solve_small

NAME = {name!r}
N = {n}
M = {m}
NP = {n_params}
NG = {n_gains}
NAUX = {n_aux}
HOLONOMIC = {holonomic}
DIAGONAL_C = {diagonal}
PARAM_NAMES = {param_names!r}
PARAM_DEFAULTS = {param_defaults}
OUTPUT_NAMES = {output_names!r}


@njit(cache=True, inline="always", error_model="numpy")
def _phi(s, p, out):
{phi_body}


@njit(cache=True, inline="always", error_model="numpy")
def _hol(s, p, out):
{hol_body}


@njit(cache=True, inline="always", error_model="numpy")
def _dyn(s, p, a0, Y):
{dyn_body}


@njit(cache=True, inline="always", error_model="numpy")
def _cg(s, p, C, G):
{cg_body}


@njit(cache=True, inline="always", error_model="numpy")
def _energy(s, p):
{energy_body}
    return e


@njit(cache=True, inline="always", error_model="numpy")
def _law(s, p, k, tol, C, G, ph, hol, u):
    """u = C^-1 (-K phi - G); returns FLAG_SINGULAR (and u = 0) if C is singular."""
    _cg(s, p, C, G)
    _phi(s, p, ph)
    if HOLONOMIC:
        _hol(s, p, hol)
        for b in range(M):
            G[b] = -k[b] * hol[b] - k[M + b] * ph[b] - G[b]
    else:
        for b in range(M):
            G[b] = -k[b] * ph[b] - G[b]
{solve_body}


@njit(cache=True, inline="always", error_model="numpy")
def _accel(s, p, u, ds):
{acc_body}


@njit(cache=True, inline="always", error_model="numpy")
def _deriv(s, p, u, a0, Y, ds):
    for i in range(N):
        ds[i] = s[N + i]
    _accel(s, p, u, ds)


@njit(cache=True, inline="always")
def _work():
    # One allocation per call (not per row): 17 work vectors, then Y and C.
    W = np.empty((17, max(2 * N, NP, NG)))
    return W, np.empty((N, M)), np.empty((M, M))


@njit(cache=True, inline="always")
def _finish(r, x, acc, substeps, flag, out, u_out, flags):
    finite = True
    for i in range(2 * N):
        out[r, i] = x[i]
        if not math.isfinite(x[i]):
            finite = False
    for a in range(M):
        u_out[r, a] = acc[a] / substeps
    if not finite:
        flag |= FLAG_NONFINITE
    flags[r] = flag


@njit(cache=True, error_model="numpy")
def _rows_open(start, stop, S, P, PL, U, K, lo, hi, dt, substeps, tol, out, u_out, flags):
    # Open loop (the environments' default): the held force needs no law, so the whole RK4 step
    # is generated as scalar code on local variables, which LLVM keeps in registers (about 3x
    # faster than the loops over work arrays that the feedback modes below use), and run as a
    # loop over the lanes of a row block, which LLVM turns into SIMD code (codegen.LANES).
    h = dt / substeps
{open_body}


@njit(cache=True, error_model="numpy")
def _rows_continuous(start, stop, S, P, PL, U, K, lo, hi, dt, substeps, tol, out, u_out, flags):
    W, Y, C = _work()
    n2 = 2 * N
    x = W[0, :n2]; k1 = W[1, :n2]; k2 = W[2, :n2]; k3 = W[3, :n2]; k4 = W[4, :n2]; tmp = W[5, :n2]
    p = W[6, :NP]; pl = W[16, :NP]; kk = W[7, :NG]; uh = W[8, :M]; u = W[9, :M]; ul = W[10, :M]; acc = W[11, :M]
    G = W[12, :M]; ph = W[13, :M]; hol = W[14, :M]; a0 = W[15, :N]
    h = dt / substeps
    for r in range(start, stop):
        flag = 0
        for i in range(n2):
            x[i] = S[r, i]
        for i in range(NP):
            p[i] = P[r, i]
            pl[i] = PL[r, i]
        for i in range(NG):
            kk[i] = K[r, i]
        for a in range(M):
            uh[a] = U[r, a]
            acc[a] = 0.0
        for _ in range(substeps):
            flag |= _law(x, pl, kk, tol, C, G, ph, hol, ul)
            for a in range(M):
                u[a] = min(max(ul[a] + uh[a], lo[a]), hi[a])
            for a in range(M):
                acc[a] += u[a]
            _deriv(x, p, u, a0, Y, k1)
            for i in range(n2):
                tmp[i] = x[i] + 0.5 * h * k1[i]
            flag |= _law(tmp, pl, kk, tol, C, G, ph, hol, ul)
            for a in range(M):
                u[a] = min(max(ul[a] + uh[a], lo[a]), hi[a])
            _deriv(tmp, p, u, a0, Y, k2)
            for i in range(n2):
                tmp[i] = x[i] + 0.5 * h * k2[i]
            flag |= _law(tmp, pl, kk, tol, C, G, ph, hol, ul)
            for a in range(M):
                u[a] = min(max(ul[a] + uh[a], lo[a]), hi[a])
            _deriv(tmp, p, u, a0, Y, k3)
            for i in range(n2):
                tmp[i] = x[i] + h * k3[i]
            flag |= _law(tmp, pl, kk, tol, C, G, ph, hol, ul)
            for a in range(M):
                u[a] = min(max(ul[a] + uh[a], lo[a]), hi[a])
            _deriv(tmp, p, u, a0, Y, k4)
            for i in range(n2):
                x[i] = x[i] + (h / 6.0) * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])
        _finish(r, x, acc, substeps, flag, out, u_out, flags)

@njit(cache=True, error_model="numpy")
def _rows_sampled(start, stop, S, P, PL, U, K, lo, hi, dt, substeps, tol, out, u_out, flags):
    W, Y, C = _work()
    n2 = 2 * N
    x = W[0, :n2]; k1 = W[1, :n2]; k2 = W[2, :n2]; k3 = W[3, :n2]; k4 = W[4, :n2]; tmp = W[5, :n2]
    p = W[6, :NP]; pl = W[16, :NP]; kk = W[7, :NG]; uh = W[8, :M]; u = W[9, :M]; ul = W[10, :M]; acc = W[11, :M]
    G = W[12, :M]; ph = W[13, :M]; hol = W[14, :M]; a0 = W[15, :N]
    h = dt / substeps
    for r in range(start, stop):
        flag = 0
        for i in range(n2):
            x[i] = S[r, i]
        for i in range(NP):
            p[i] = P[r, i]
            pl[i] = PL[r, i]
        for i in range(NG):
            kk[i] = K[r, i]
        for a in range(M):
            uh[a] = U[r, a]
            acc[a] = 0.0
        flag |= _law(x, pl, kk, tol, C, G, ph, hol, ul)
        for a in range(M):
            uh[a] += ul[a]
        for _ in range(substeps):
            for a in range(M):
                u[a] = min(max(uh[a], lo[a]), hi[a])
            for a in range(M):
                acc[a] += u[a]
            _deriv(x, p, u, a0, Y, k1)
            for i in range(n2):
                tmp[i] = x[i] + 0.5 * h * k1[i]
            for a in range(M):
                u[a] = min(max(uh[a], lo[a]), hi[a])
            _deriv(tmp, p, u, a0, Y, k2)
            for i in range(n2):
                tmp[i] = x[i] + 0.5 * h * k2[i]
            for a in range(M):
                u[a] = min(max(uh[a], lo[a]), hi[a])
            _deriv(tmp, p, u, a0, Y, k3)
            for i in range(n2):
                tmp[i] = x[i] + h * k3[i]
            for a in range(M):
                u[a] = min(max(uh[a], lo[a]), hi[a])
            _deriv(tmp, p, u, a0, Y, k4)
            for i in range(n2):
                x[i] = x[i] + (h / 6.0) * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])
        _finish(r, x, acc, substeps, flag, out, u_out, flags)


@njit(cache=True)
def _rows(mode, start, stop, S, P, PL, U, K, lo, hi, dt, substeps, tol, out, u_out, flags):
    if mode == 0:
        _rows_open(start, stop, S, P, PL, U, K, lo, hi, dt, substeps, tol, out, u_out, flags)
    elif mode == 1:
        _rows_continuous(start, stop, S, P, PL, U, K, lo, hi, dt, substeps, tol, out, u_out, flags)
    else:
        _rows_sampled(start, stop, S, P, PL, U, K, lo, hi, dt, substeps, tol, out, u_out, flags)


@njit(cache=True)
def rk4(S, P, U, K, mode, lo, hi, dt, substeps, tol, out, u_out, flags):
    """Batched RK4 over rows of S (B, 2N); P (B, NP), U (B, M), K (B, NG).

    mode 0 (open): u = clip(U) held.  mode 1 (continuous): u = clip(u*(stage) + U) at every
    RK4 stage.  mode 2 (sampled): u = clip(u*(start) + U), evaluated once and held over the
    control period dt (split into `substeps` RK4 steps).  u_out gets the mean applied control.
    """
    _rows(mode, 0, S.shape[0], S, P, P, U, K, lo, hi, dt, substeps, tol, out, u_out, flags)


@njit(cache=True, parallel=True)
def rk4_parallel(S, P, U, K, mode, lo, hi, dt, substeps, tol, out, u_out, flags, n_chunks):
    """rk4 split into n_chunks row blocks run on numba's thread pool."""
    B = S.shape[0]
    for c in prange(n_chunks):
        _rows(mode, c * B // n_chunks, (c + 1) * B // n_chunks, S, P, P, U, K, lo, hi, dt, substeps, tol,
              out, u_out, flags)


@njit(cache=True, error_model="numpy")
def _phi_rows(start, stop, S, P, out):
    # phi of rows start:stop, as a loop over the lanes of row blocks (SIMD); every batched phi
    # (a step, a reset, the public kernel) comes from here, so they agree to the bit.
{phi_rows_body}


@njit(cache=True, error_model="numpy")
def _aux_rows(start, stop, S, P, out):
    # The extra outputs of rows start:stop, as _phi_rows.
{aux_rows_body}


@njit(cache=True, error_model="numpy")
def _phi_idx(rows, S, P, out):
    # _phi_rows for the rows listed in rows (a reset's rows), in lanes of those rows.
    start = 0
    stop = rows.shape[0]
{phi_idx_body}


@njit(cache=True, error_model="numpy")
def _aux_idx(rows, S, P, out):
    # _aux_rows for the rows listed in rows.
    start = 0
    stop = rows.shape[0]
{aux_idx_body}


@njit(cache=True)
def _advance_rows(start, stop, S, P, U, K, mode, lo, hi, dt, substeps, tol, NEXT, u_out, flags, DV, PHI, PA, AUX):
    _rows(mode, start, stop, S, P, PA, U, K, lo, hi, dt, substeps, tol, NEXT, u_out, flags)
    kicks = DV.shape[0] > 0  # DV with no rows: no kicks (not read at all)
    for r in range(start, stop):
        if kicks:
            for j in range(N):
                NEXT[r, N + j] += DV[r, j]
        if (flags[r] & FLAG_NONFINITE) == 0:
            for j in range(2 * N):
                S[r, j] = NEXT[r, j]
    _phi_rows(start, stop, S, P, PHI)
    _aux_rows(start, stop, S, PA, AUX)


@njit(cache=True)
def advance(S, P, U, K, mode, lo, hi, dt, substeps, tol, NEXT, u_out, flags, DV, PHI, PA, AUX):
    """One environment step for all rows: rk4 into NEXT, add velocity kicks DV (B, N; or (0, N): none), accept
    finite rows into S (rows with FLAG_NONFINITE keep their old state), then phi(S, P) -> PHI and
    the extra outputs aux(S, PA) -> AUX.  P drives the dynamics; PA (e.g. the nominal model a
    controller is told) is used by the in-loop law (modes 1, 2) and the extra outputs."""
    _advance_rows(0, S.shape[0], S, P, U, K, mode, lo, hi, dt, substeps, tol, NEXT, u_out, flags, DV, PHI, PA, AUX)


@njit(cache=True, parallel=True)
def advance_parallel(S, P, U, K, mode, lo, hi, dt, substeps, tol, NEXT, u_out, flags, DV, PHI, PA, AUX, n_chunks):
    """advance split into n_chunks row blocks on numba's thread pool."""
    B = S.shape[0]
    for c in prange(n_chunks):
        _advance_rows(c * B // n_chunks, (c + 1) * B // n_chunks, S, P, U, K, mode, lo, hi, dt, substeps, tol,
                      NEXT, u_out, flags, DV, PHI, PA, AUX)


@njit(cache=True)
def law(S, P, K, tol, U, flags):
    """Batched u* (K = 0 gives u_hat); flags[r] = FLAG_SINGULAR where C is singular."""
    C = np.empty((M, M))
    G = np.empty(M)
    ph = np.empty(M)
    hol = np.empty(M)
    for r in range(S.shape[0]):
        flags[r] = _law(S[r], P[r], K[r], tol, C, G, ph, hol, U[r])


@njit(cache=True)
def phi(S, P, out):
    _phi_rows(0, S.shape[0], S, P, out)


@njit(cache=True)
def phi_h(S, P, out):
    for r in range(S.shape[0]):
        _hol(S[r], P[r], out[r])


@njit(cache=True)
def cg(S, P, C, G):
    for r in range(S.shape[0]):
        _cg(S[r], P[r], C[r], G[r])


@njit(cache=True)
def dyn(S, P, A0, Y):
    for r in range(S.shape[0]):
        _dyn(S[r], P[r], A0[r], Y[r])


@njit(cache=True)
def energy(S, P, out):
    for r in range(S.shape[0]):
        out[r] = _energy(S[r], P[r])


@njit(cache=True)
def aux(S, P, out):
    _aux_rows(0, S.shape[0], S, P, out)


@njit(cache=True)
def phi_at(rows, S, P, out):
    """phi of the listed rows of the full arrays S, P into out[rows] (a reset's rows)."""
    _phi_idx(rows, S, P, out)


@njit(cache=True)
def aux_at(rows, S, P, out):
    """The extra outputs of the listed rows into out[rows], as phi_at."""
    _aux_idx(rows, S, P, out)
'''
