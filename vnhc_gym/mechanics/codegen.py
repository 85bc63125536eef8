"""Turn a [`SymbolicLaw`][vnhc_gym.mechanics.constraint.SymbolicLaw] into a compiled, cached module.

Why code generation: the law and an RK4 step are a few dozen flops per system, so numpy would be
dominated by per-call overhead (about 1 us per array operation).  Here each symbolic quantity
(the acceleration, ``phi``, ``C`` and ``G``, the extra outputs, ...) becomes one numba function of
straight-line scalar code with its common subexpressions computed once, and the batch kernels
around them (RK4 with its feedback modes, the law) are the text of a real module,
`vnhc_gym.mechanics._system_template`, with its placeholder import replaced by those functions.

Every sine and cosine is printed as the inline polynomial ``psin``/``pcos``
(`vnhc_gym.mechanics.numerics`): the same bits on every machine, whatever its libm.

The module is cached on disk under a key that hashes everything it is made from
(`module_key`): the symbolic input or a recipe with the files that define it, and the text
of this file, the template and the core files.  Only generating a module imports sympy; loading a
cached one does not.
"""

from __future__ import annotations

import hashlib
import math
import os
from collections.abc import Iterable, Mapping
from functools import cache
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # sympy is imported by the functions that generate code, never on a warm start
    import sympy as sp

    from vnhc_gym.mechanics.constraint import SymbolicLaw

__all__ = ["CODEGEN_VERSION", "CORE_SOURCES", "fill_template", "generate_source", "module_key", "recipe_parts",
           "sources_digest", "splice"]

#: Bumped when the generated text changes in a way the hashed sources do not show.
CODEGEN_VERSION = "20"

_HERE = Path(__file__).parent
#: Files whose text shapes every generated module; their hash is part of every module's key.
CORE_SOURCES: tuple[Path, ...] = tuple(_HERE / f for f in ("codegen.py", "_system_template.py", "numerics.py",
                                                           "system.py", "constraint.py"))


def sources_digest(paths: Iterable[str | os.PathLike[str]]) -> str:
    """sha256 over the names and contents of ``paths``.

    File names, not folders, enter the hash, so the key does not depend on where the package is
    installed.
    """
    h = hashlib.sha256()
    for path in paths:
        data = Path(path).read_bytes()
        h.update(f"{Path(path).name}\x00{len(data)}\x00".encode())
        h.update(data)
    return h.hexdigest()


def module_key(parts: Iterable[str], sources: Iterable[str | os.PathLike[str]] = ()) -> str:
    """Cache key of a generated module: ``parts`` (what it is made of), ``CODEGEN_VERSION`` and the
    text of ``CORE_SOURCES`` plus ``sources``."""
    digest = sources_digest([*CORE_SOURCES, *sources])
    return hashlib.sha256("\x00".join([CODEGEN_VERSION, digest, *parts]).encode()).hexdigest()[:24]


def recipe_parts(recipe: tuple[object, ...]) -> list[str]:
    """Key parts of a recipe such as ``("usv", "random")``: items must be str, int, float or bool
    (their ``repr`` is stable across processes)."""
    if not isinstance(recipe, tuple) or not recipe:
        raise TypeError(f"recipe must be a non-empty tuple, got {recipe!r}")
    for item in recipe:
        if type(item) not in (str, int, float, bool):
            raise TypeError(f"recipe items must be str, int, float or bool, got {type(item).__name__} in {recipe!r}")
    return ["recipe", repr(recipe)]


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


def _literal(value: float) -> str:
    """A float as Python source (``repr`` round-trips exactly; inf and nan need a call)."""
    return repr(value) if math.isfinite(value) else f"float({str(value)!r})"


class _Writer:
    """Writes the expression functions of one system (numba functions on rows ``s``, ``p``)."""

    def __init__(self, law: SymbolicLaw) -> None:
        system = law.system
        self.state_syms = list(system.q) + list(system.qd)
        self.param_syms = list(system.param_symbols)
        self.printer = _printer_class()({"fully_qualified_modules": True, "standard": "python3"})

    def body(self, assignments: list[tuple[str, sp.Expr]], extra_reads: str = "", state: str = "s",
             indexed: bool = False) -> list[str]:
        """Straight-line code for ``target = expr`` pairs with shared subexpressions, reading only
        the state and parameter entries the expressions use (``s[i]``, ``p[i]``; ``s[si[i]]``,
        ``p[pi[i]]`` if ``indexed``).

        The state entries are named ``<state>_i``.  The name matters to the last bit: sympy orders
        the terms of a sum by their symbols' names, and floating-point sums depend on the order.
        """
        import sympy as sp

        subs = {x: sp.Symbol(f"{state}_{i}") for i, x in enumerate(self.state_syms)}
        subs.update({x: sp.Symbol(f"p_{i}") for i, x in enumerate(self.param_syms)})
        exprs = [sp.sympify(e) for _, e in assignments]
        free: set[sp.Symbol] = set().union(*(e.free_symbols for e in exprs)) if exprs else set()
        si, pi = ("si[{}]", "pi[{}]") if indexed else ("{}", "{}")
        reads = [f"{state}_{i} = s[{si.format(i)}]" for i, x in enumerate(self.state_syms) if x in free]
        reads += [f"p_{i} = p[{pi.format(i)}]" for i, x in enumerate(self.param_syms) if x in free]
        temps, reduced = sp.cse([e.xreplace(subs) for e in exprs], symbols=sp.numbered_symbols("t_"),
                                optimizations="basic")
        lines = ["; ".join(reads)] if reads else []
        if extra_reads:
            lines.append(extra_reads)
        for sym, expr in temps:
            lines.append(f"{sym} = {self.code(expr)}")
        for (target, _), expr in zip(assignments, reduced, strict=True):
            lines.append(f"{target} = {self.code(expr)}")
        return lines or ["pass"]

    def code(self, expr: sp.Expr) -> str:
        import sympy as sp

        text = self.printer.doprint(sp.Float(expr) if expr.is_Number else expr)
        return text.replace("math.sin(", "psin(").replace("math.cos(", "pcos(")

    def function(self, signature: str, doc: str, lines: list[str], returns: str | None = None) -> str:
        out = ["@njit(cache=True, error_model=\"numpy\")", f"def {signature}:", f'    """{doc}"""']
        out += ["    " + line for line in lines]
        if returns:
            out.append(f"    return {returns}")
        return "\n".join(out)


def generate_source(law: SymbolicLaw, outputs: Mapping[str, sp.Expr] | None = None) -> str:
    """Python source of the compiled module of ``law``: the template with this system's functions.

    Besides the kernels, the module records what [`ConstrainedSystem`][vnhc_gym.mechanics.ConstrainedSystem]
    needs to run without sympy: ``NAME``, ``N``, ``M``, ``NP``, ``NG``, ``NAUX``, ``HOLONOMIC``,
    ``BLOCK``, ``PARAM_NAMES``, ``PARAM_DEFAULTS``, ``PARAM_POSITIVE`` and ``OUTPUT_NAMES``.
    """
    import sympy as sp

    system = law.system
    n, m = system.n, system.m
    outputs = dict(outputs or {})
    w = _Writer(law)
    u_syms = [sp.Symbol(f"u_{a}") for a in range(m)]
    accel = law.a0 + law.Y * sp.Matrix(u_syms)  # written out with u as symbols: Y's zeros cost nothing
    used_u = [a for a in range(m) if any(u_syms[a] in e.free_symbols for e in accel)]
    diagonal = all(sp.simplify(law.C[b, a]) == 0 for b in range(m) for a in range(m) if a != b)
    defaults = ", ".join(_literal(v) for v in system.default_param_values())
    phi_h = law.phi_h if law.phi_h is not None else sp.zeros(m, 1)
    jn, yn = law.factor_sizes()
    positive = system.param_positive
    outs = list(outputs.values())
    functions = [
        # The stage state of RK4 is z (the name fixes the order of the sums; see _Writer.body).
        w.function("_accel(s, p, u, ds)", "ds[N:] = a0(s) + Y(s) u.",
                   w.body([(f"ds[{n + i}]", accel[i]) for i in range(n)],
                          "; ".join(f"u_{a} = u[{a}]" for a in used_u), state="z")),
        w.function("_phi(s, p, out)", "out = phi(s).", w.body([(f"out[{b}]", law.phi[b]) for b in range(m)])),
        # The same, reading s[si], p[pi], u[ui] and writing at indices: a fleet's unit works in place.
        w.function("_accel_at(s, p, u, ds, si, pi, ui)", "ds[si[N:]] = a0 + Y u of s[si], p[pi], u[ui].",
                   w.body([(f"ds[si[{n + i}]]", accel[i]) for i in range(n)],
                          "; ".join(f"u_{a} = u[ui[{a}]]" for a in used_u), state="z", indexed=True)),
        w.function("_phi_at(s, p, out, si, pi, oi)", "out[oi] = phi of s[si], p[pi].",
                   w.body([(f"out[oi[{b}]]", law.phi[b]) for b in range(m)], indexed=True)),
        w.function("_aux_at(s, p, out, si, pi, oi)", "out[oi] = the extra outputs of s[si], p[pi].",
                   w.body([(f"out[oi[{j}]]", e) for j, e in enumerate(outs)], indexed=True)),
        w.function("_phi_h(s, p, out)", "out = phi_h(q) (holonomic constraints).",
                   w.body([(f"out[{b}]", phi_h[b]) for b in range(m)])),
        w.function("_aux(s, p, out)", "The extra outputs.",
                   w.body([(f"out[{j}]", e) for j, e in enumerate(outputs.values())])),
        w.function("_cg(s, p, C, G)", "C (by block rows) and G(phi).",
                   w.body([(f"C[{b}, {0 if diagonal else a}]", law.C[b, a]) for b in range(m) for a in range(m)
                           if not diagonal or a == b]
                          + [(f"G[{b}]", law.G[b]) for b in range(m)])),
        w.function("_tn(s, p, sizes)", "The squared sizes of the singular test: J_b M^-1 J_b^T, then f^a . Y^a.",
                   w.body([(f"sizes[{b}]", jn[b]) for b in range(m)]
                          + [(f"sizes[{m + a}]", yn[a]) for a in range(m)])),
        # A function of its own, not one body with _cg: C's bits must not depend on the extra terms.
        w.function("_cgn(s, p, C, G, sizes)", "C (by block rows), G(phi) and the squared sizes.",
                   ["_cg(s, p, C, G)", "_tn(s, p, sizes)"]),
        w.function("_dyn(s, p, a0, Y)", "Drift a0 and input fields Y.",
                   w.body([(f"a0[{i}]", law.a0[i]) for i in range(n)]
                          + [(f"Y[{i}, {a}]", law.Y[i, a]) for i in range(n) for a in range(m)])),
        w.function("_energy(s, p)", "Mechanical energy.", w.body([("e", law.energy)]), returns="e"),
    ]
    constants = [
        f"NAME = {system.name!r}", f"N = {n}", f"M = {m}", f"NP = {len(w.param_syms)}", f"NG = {law.n_gains}",
        f"NAUX = {len(outputs)}", f"HOLONOMIC = {law.phi_h is not None}", f"BLOCK = {1 if diagonal else m}",
        f"PARAM_NAMES = {tuple(str(p) for p in w.param_syms)!r}",
        f"PARAM_DEFAULTS = ({defaults}{',' if len(w.param_syms) == 1 else ''})",
        f"PARAM_POSITIVE = {positive!r}",
        f"OUTPUT_NAMES = {tuple(outputs)!r}",
    ]
    block = "\n".join(constants) + "\n\n\n" + "\n\n\n".join(functions) + "\n\n"
    return fill_template(_HERE / "_system_template.py", "system", block, f"system {system.name!r}")


def splice(text: str, marker: str, block: str) -> str:
    """``text`` with the lines between its ``# --- <marker>: begin`` and ``# --- <marker>: end`` lines
    (both included) replaced by ``block``."""
    lines = text.splitlines(keepends=True)
    try:
        begin = next(i for i, line in enumerate(lines) if line.startswith(f"# --- {marker}: begin"))
        end = next(i for i, line in enumerate(lines) if line.startswith(f"# --- {marker}: end"))
    except StopIteration:  # pragma: no cover - the templates are part of the package
        raise RuntimeError(f"template has no {marker!r} markers") from None
    return "".join(lines[:begin]) + block + "".join(lines[end + 1:])


def fill_template(template: str | os.PathLike[str], marker: str, block: str, what: str) -> str:
    """The text of the module ``template`` with its ``marker`` block replaced by ``block`` (see
    `splice`), headed by a line that says it is generated."""
    head = f"# Generated by vnhc_gym from {Path(template).name} for {what}; do not edit (delete to regenerate).\n"
    return head + splice(Path(template).read_text(encoding="utf-8"), marker, block)
