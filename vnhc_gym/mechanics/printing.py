"""Print a system's law as an ordinary Python module of pure ``jax.numpy`` functions.

sympy stays the source of truth: [`derive_law`][vnhc_gym.mechanics.derive_law] gives the drift
acceleration ``a0``, the input fields ``Y``, the constraint ``phi`` (and ``phi_h`` for a holonomic
one), the decoupling matrix ``C``, the drift term ``G``, the squared sizes of ``C``'s factors (the
law's singular test) and the energy; this module prints each as
one function of a single state ``s`` (shape ``(2n,)``) and parameter vector ``p``, with its common
subexpressions computed once.  The printed text is a module a reader opens like any other (it is
shipped in the package and imported, never written to a cache), and
[`vnhc_gym.mechanics.functional`][vnhc_gym.mechanics.functional] builds RK4, the zero-order hold
and the law on top of it.  Batching is ``jax.vmap`` from outside.

Why printed once rather than lambdified at import: deriving ``C`` and ``G`` takes sympy seconds to
minutes per system (the spacecraft's simplification most), which every first use would pay.
"""

from __future__ import annotations

import keyword
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import sympy as sp

    from vnhc_gym.mechanics.constraint import SymbolicLaw

__all__ = ["print_module"]


def _names(symbols: Sequence[sp.Symbol], prefix: str, taken: set[str]) -> list[str]:
    """Python names for ``symbols``: their own where that is a fresh identifier, else ``prefix<i>``."""
    out = []
    for i, sym in enumerate(symbols):
        name = str(sym)
        if not name.isidentifier() or keyword.iskeyword(name) or name in taken or name.startswith("_"):
            name = f"{prefix}{i}"
        taken.add(name)
        out.append(name)
    return out


def _function(name: str, doc: str, exprs: list[sp.Expr], shape: tuple[int, ...], state: dict[sp.Symbol, str],
              params: dict[sp.Symbol, str], printer: object) -> str:
    """One pure function ``name(s, p)`` returning ``exprs`` as an array of ``shape``, straight-line code
    with shared subexpressions (``_c<k>``) computed once, reading only the entries it uses."""
    import sympy as sp

    replacements, reduced = sp.cse(exprs, symbols=sp.numbered_symbols("_c"), optimizations="basic")
    used = set().union(*(e.free_symbols for e in reduced), *(e.free_symbols for _, e in replacements))
    lines = [f"def {name}(s, p):", f'    """{doc}"""']
    names = {**state, **params}
    s_used = [(i, v) for i, (k, v) in enumerate(state.items()) if k in used]
    p_used = [(i, v) for i, (k, v) in enumerate(params.items()) if k in used]
    lines += [f"    {v} = s[{i}]" for i, v in s_used]
    lines += [f"    {v} = p[{i}]" for i, v in p_used]

    def text(e: sp.Expr) -> str:
        e = e.xreplace({k: sp.Symbol(v) for k, v in names.items()})
        return printer.doprint(e).replace("jax.numpy.", "jnp.")  # type: ignore[attr-defined]

    lines += [f"    {sym} = {text(e)}" for sym, e in replacements]
    # A constant entry takes the state's dtype (and batches through vmap) as ``full_like(s[0], c)``.
    items = ", ".join(text(e) if e.free_symbols else f"jnp.full_like(s[0], {text(e)})" for e in reduced)
    lines.append(f"    return jnp.reshape(jnp.stack([{items}]), {shape!r})")
    return "\n".join(lines)


def print_module(law: SymbolicLaw, title: str, source: str, outputs: Mapping[str, sp.Expr] | None = None) -> str:
    """The text of a module of pure ``jax.numpy`` functions for ``law``.

    Parameters
    ----------
    law : SymbolicLaw
        The derived law of one system and constraint.
    title : str
        What the module is (its docstring's first line).
    source : str
        Where it is printed from (a function call a reader can find), for the docstring.
    outputs : mapping of str to sympy expression, optional
        Extra quantities of the state and parameters (the sea current at the boat, say), printed
        as ``outputs(s, p)`` in this order.

    Returns
    -------
    str
        The module: ``NAME``, ``N``, ``M``, ``STATE_NAMES``, ``PARAM_NAMES``, ``PARAM_DEFAULTS``,
        ``PARAM_POSITIVE``, ``OUTPUT_NAMES``, ``HOLONOMIC`` and the functions ``drift`` (``a0``,
        shape ``(n,)``), ``input_fields`` (``Y``, ``(n, m)``), ``phi`` (``(m,)``), ``phi_h``
        (holonomic only), ``decoupling_matrix`` (``C``, ``(m, m)``), ``drift_term`` (``G``,
        ``(m,)``), ``singular_sizes`` (``(2m,)``, see
        [`SymbolicLaw.factor_sizes`][vnhc_gym.mechanics.SymbolicLaw.factor_sizes]), ``energy``
        (``()``) and ``outputs``.
    """
    from sympy.printing.numpy import JaxPrinter

    system = law.system
    n, m = system.n, system.m
    taken: set[str] = {"s", "p", "jnp"}
    q_syms = list(system.q) + list(system.qd)
    state = dict(zip(q_syms, _names(q_syms, "s_", taken), strict=True))
    p_syms = list(system.param_symbols)
    params = dict(zip(p_syms, _names(p_syms, "p_", taken), strict=True))
    printer = JaxPrinter({"fully_qualified_modules": True})
    outputs = dict(outputs or {})
    jn, yn = law.factor_sizes()
    functions = [
        ("drift", "Drift acceleration ``a0`` (no control), shape ``(n,)``.", list(law.a0), (n,)),
        ("input_fields", "Input fields ``Y`` (column ``a``: the acceleration of unit control ``a``), shape "
         "``(n, m)``.", list(law.Y), (n, m)),
        ("phi", "The constraint ``phi`` (``psi`` for a holonomic one), shape ``(m,)``.", list(law.phi), (m,)),
        ("decoupling_matrix", "Decoupling matrix ``C = d phi / d qd . Y``, shape ``(m, m)``.", list(law.C), (m, m)),
        ("drift_term", "``G``: the rate of ``phi`` along the drift, shape ``(m,)``.", list(law.G), (m,)),
        ("singular_sizes", "Squared sizes ``|J_b|^2`` then ``|Y^a|^2`` of the factors of ``C = J Y`` (the law's "
         "singular test), shape ``(2 m,)``.", [*jn, *yn], (2 * m,)),
        ("energy", "Mechanical energy, a scalar.", [law.energy], ()),
    ]
    if law.phi_h is not None:
        functions.append(("phi_h", "Holonomic constraint values, shape ``(m,)``.", list(law.phi_h), (m,)))
    if outputs:
        functions.append(("outputs", f"Extra outputs {tuple(outputs)}, shape ``({len(outputs)},)``.",
                          list(outputs.values()), (len(outputs),)))
    defaults = [float(system.params[s]) for s in p_syms]
    head = [
        f'"""{title}.',
        "",
        f"Printed from ``{source}`` by ``python -m vnhc_gym.systems.printed``: do not edit, regenerate.",
        "Every function takes one state ``s`` (``q`` then ``qd``) and one parameter vector ``p``.",
        '"""',
        "",
        "import jax.numpy as jnp",
        "",
        f"NAME = {system.name!r}",
        f"N = {n}",
        f"M = {m}",
        f"STATE_NAMES = {tuple(str(s) for s in q_syms)!r}",
        f"PARAM_NAMES = {tuple(str(s) for s in p_syms)!r}",
        f"PARAM_DEFAULTS = {tuple(defaults)!r}",
        f"PARAM_POSITIVE = {tuple(system.param_positive)!r}",
        f"OUTPUT_NAMES = {tuple(outputs)!r}",
        f"HOLONOMIC = {law.phi_h is not None!r}",
    ]
    body = [_function(name, doc, exprs, shape, state, params, printer) for name, doc, exprs, shape in functions]
    return "\n".join(head) + "\n\n\n" + "\n\n\n".join(body) + "\n"
