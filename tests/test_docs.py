"""The documentation site builds with ``mkdocs build --strict`` and stands alone.

The build needs the ``docs`` extra (MkDocs, Material, mkdocstrings); without it the build test is
skipped.  The build reads the package with a static analyser (griffe), so it never imports
vnhc_gym, JAX or sympy, and takes a few seconds.  Docstrings cross-reference with autorefs'
``[`Name`][vnhc_gym.path]``, never with Sphinx roles, which the site would show raw: the sources
are scanned without the build, the built pages with it.
"""

from __future__ import annotations

import ast
import importlib.util
import io
import os
import re
import subprocess
import sys
import tokenize
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
DOCS = REPO / "docs"
PACKAGE = REPO / "vnhc_gym"

#: Import names of what ``mkdocs.yml`` needs (mkdocs, mkdocs-material, mkdocstrings[python],
#: pymdown-extensions, griffe-sphinx).
DOCS_MODULES = ("mkdocs", "material", "mkdocstrings", "mkdocstrings_handlers.python", "pymdownx", "griffe_sphinx")

#: Pages that must come out of the build (site paths, ``use_directory_urls`` layout).
EXPECTED_PAGES = ("index.html", "getting-started/index.html", "math/index.html", "errata/index.html",
                  "design/index.html", "api/mechanics/index.html", "api/stats/index.html")

#: Objects whose documentation the API pages must render (anchor ids written by mkdocstrings).
EXPECTED_OBJECTS = {
    "api/mechanics/index.html": ("vnhc_gym.mechanics.system.MechanicalSystem", "vnhc_gym.mechanics.ConstrainedSystem",
                                 "vnhc_gym.mechanics.constraint.derive_law"),
    "api/stats/index.html": ("vnhc_gym.stats", "vnhc_gym.stats.iqm", "vnhc_gym.stats.interval_estimates"),
}

#: Material the site must not point to: the paper's sources live outside the repository.
FORBIDDEN_TEXT = ("../shared", "NOTES.md", "geometric-stabilization-vnhc.tex")

#: Absolute file-system paths (POSIX roots outside a repository, Windows drives, file: URLs).
ABSOLUTE_PATH = re.compile(r"(?<![\w.:/-])(?:/(?:work|home|root|tmp|mnt|Users|opt|srv|var|usr|etc)/"
                           r"|[A-Za-z]:\\|file:/)")


#: A Sphinx role (``:class:`Name```): mkdocstrings does not render it, the site would show it raw.  A
#: docstring cross-references a documented object as ``[`Name`][vnhc_gym.full.path]`` (autorefs) and
#: names anything else in plain code.
SPHINX_ROLE = re.compile(r":(?:class|meth|func|mod|attr|data|exc|obj):")


def _docstring_lines(tree: ast.Module) -> set[int]:
    """Source lines of every docstring griffe reads: a module's, class's or function's first
    statement, and the string right after an assignment (an attribute's docstring)."""
    lines: set[int] = set()
    for node in ast.walk(tree):
        if not isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            continue
        body = node.body
        strings = [body[0]] if body else []
        strings += [nxt for prev, nxt in zip(body[:-1], body[1:], strict=True)
                    if isinstance(prev, (ast.Assign, ast.AnnAssign))]
        for stmt in strings:
            if isinstance(stmt, ast.Expr) and isinstance(stmt.value, ast.Constant) \
                    and isinstance(stmt.value.value, str):
                lines.update(range(stmt.lineno, (stmt.end_lineno or stmt.lineno) + 1))
    return lines


def _raw_roles(path: Path, root: Path = REPO) -> list[str]:
    """``file:line: text`` of every Sphinx role in the docstrings and comments of ``path`` (comments
    too: a ``#:`` comment is an attribute's docstring)."""
    source = path.read_text(encoding="utf-8")
    doc_lines = _docstring_lines(ast.parse(source))
    hits = []
    for tok in tokenize.generate_tokens(io.StringIO(source).readline):
        if tok.type == tokenize.COMMENT or (tok.type == tokenize.STRING and tok.start[0] in doc_lines):
            for offset, line in enumerate(tok.string.splitlines()):
                if SPHINX_ROLE.search(line):
                    hits.append(f"{path.relative_to(root)}:{tok.start[0] + offset}: {line.strip()[:120]}")
    return hits


def _missing_docs_modules() -> list[str]:
    missing = []
    for name in DOCS_MODULES:
        try:
            found = importlib.util.find_spec(name) is not None
        except ModuleNotFoundError:  # parent package absent (mkdocstrings_handlers)
            found = False
        if not found:
            missing.append(name)
    return missing


def _offending_lines(text: str) -> list[str]:
    hits = []
    for number, line in enumerate(text.splitlines(), 1):
        if any(s.lower() in line.lower() for s in FORBIDDEN_TEXT) or ABSOLUTE_PATH.search(line) \
                or str(REPO) in line:
            hits.append(f"{number}: {line.strip()[:160]}")
    return hits


@pytest.fixture(scope="module")
def site(tmp_path_factory: pytest.TempPathFactory) -> Path:
    missing = _missing_docs_modules()
    if missing:
        pytest.skip(f"the docs extra is not installed (missing modules: {', '.join(missing)}); "
                    "install it with: pip install -e '.[docs]'")
    out = tmp_path_factory.mktemp("site")
    # No -q: at that log level MkDocs drops warnings before --strict can count them.
    cmd = [sys.executable, "-m", "mkdocs", "build", "--strict", "--config-file", str(REPO / "mkdocs.yml"),
           "--site-dir", str(out)]
    proc = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=300,
                          env={**os.environ, "NO_MKDOCS_2_WARNING": "1"})  # silence Material's banner
    log = proc.stdout + proc.stderr
    assert proc.returncode == 0, f"mkdocs build --strict failed:\n{log}"
    warnings = [line for line in log.splitlines() if line.startswith(("WARNING", "ERROR"))]
    assert not warnings, "\n".join(warnings)
    return out


def test_site_builds_strict(site: Path) -> None:
    for page in EXPECTED_PAGES:
        assert (site / page).is_file(), f"{page} missing from the built site"
    for page, objects in EXPECTED_OBJECTS.items():
        html = (site / page).read_text(encoding="utf-8")
        for obj in objects:
            assert f'id="{obj}"' in html, f"{page} does not document {obj}"
    math = (site / "math" / "index.html").read_text(encoding="utf-8")
    assert math.count('class="arithmatex"') > 50  # the formulas went through pymdownx.arithmatex


def test_docstrings_have_no_sphinx_roles() -> None:
    sources = sorted(PACKAGE.rglob("*.py"))
    assert len(sources) > 20, "vnhc_gym sources not found"
    hits = [hit for path in sources for hit in _raw_roles(path)]
    assert not hits, ("Sphinx roles in docstrings or comments (mkdocstrings shows them raw; write "
                      "[`Name`][vnhc_gym.full.path] for a documented object, `name` otherwise):\n" + "\n".join(hits))


def test_role_scan_finds_roles(tmp_path: Path) -> None:
    # The scan must see a role in a module, class or attribute docstring and in a comment, and
    # ignore one in an ordinary string.
    sample = tmp_path / "sample.py"
    sample.write_text('"""Module, see :class:`A`."""\n'
                      "X = 1\n"
                      '"""Attribute, see :data:`X`."""\n'
                      "#: Comment, see :func:`f`.\n"
                      "Y = 2\n"
                      "class A:\n"
                      '    """Class, see :meth:`f`."""\n'
                      'MESSAGE = f"not a docstring :class:`{X}`"\n', encoding="utf-8")
    hits = _raw_roles(sample, root=tmp_path)
    assert [h.split(":")[1] for h in hits] == ["1", "3", "4", "7"], hits


def test_rendered_site_has_no_sphinx_roles(site: Path) -> None:
    offending = {}
    for page in sorted(site.rglob("*.html")):
        text = re.sub(r"<[^>]+>", "", page.read_text(encoding="utf-8"))  # visible text: ":class:<code>X</code>"
        if hits := sorted({m.group(0) for m in SPHINX_ROLE.finditer(text)}):
            offending[str(page.relative_to(site))] = hits
    assert not offending, f"raw Sphinx roles in the built site (check the docstrings): {offending}"


def test_pages_reference_nothing_outside_the_repository() -> None:
    pages = sorted(DOCS.rglob("*.md"))
    assert pages, "no Markdown pages under docs/"
    offending = {str(p.relative_to(REPO)): hits for p in pages if (hits := _offending_lines(p.read_text("utf-8")))}
    assert not offending, f"pages pointing outside the repository: {offending}"


def test_rendered_site_references_nothing_outside_the_repository(site: Path) -> None:
    # Docstrings rendered by mkdocstrings become part of the site too.
    offending = {}
    for page in sorted(site.rglob("*.html")):
        text = re.sub(r"<[^>]+>", " ", page.read_text(encoding="utf-8"))  # visible text only
        if hits := _offending_lines(text):
            offending[str(page.relative_to(site))] = hits
    assert not offending, f"rendered pages pointing outside the repository (check the docstrings): {offending}"


def test_every_shipped_environment_has_a_card_page() -> None:
    """Each of the package's own tasks has its page under ``docs/envs/`` that renders its environment
    class's card, a row in the environments overview, and an entry in the site's nav."""
    from vnhc_gym.tasks import shipped_tasks

    nav = (REPO / "mkdocs.yml").read_text(encoding="utf-8")
    overview = (DOCS / "envs" / "index.md").read_text(encoding="utf-8")
    tasks = shipped_tasks()
    assert tasks
    for name, entry in tasks.items():
        page = DOCS / "envs" / f"{name}.md"
        assert page.is_file(), f"no card page {page.relative_to(REPO)}"
        text = page.read_text(encoding="utf-8")
        assert f"::: {entry.module}.{entry.env_name}Env" in text, f"{page.name} does not render {entry.env_name}Env"
        assert f"vnhc_gym/{entry.env_name}-v1" in text, page.name
        assert f"envs/{name}.md" in nav, f"envs/{name}.md is not in the nav of mkdocs.yml"
        assert f"[`vnhc_gym/{entry.env_name}-v1`]({name}.md)" in overview, f"envs/index.md has no row for {name}"


def test_card_pages_render_the_cards(site: Path) -> None:
    """The built card page of every shipped task shows its card's sections (mkdocstrings rendered
    the class docstring)."""
    from vnhc_gym.tasks import shipped_tasks

    for name in shipped_tasks():
        html = re.sub(r"<[^>]+>", " ", (site / "envs" / name / "index.html").read_text(encoding="utf-8"))
        for section in ("Description", "Action Space", "Observation Space", "Rewards", "Starting State",
                        "Episode End", "Arguments", "Scenarios", "Info", "Version History"):
            assert section in html, f"envs/{name}: the card's {section!r} is not on the page"
