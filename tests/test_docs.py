"""The documentation site builds with ``mkdocs build --strict`` and stands alone.

The build needs the ``docs`` extra (MkDocs, Material, mkdocstrings); without it the build test is
skipped.  The build reads the package with a static analyser (griffe), so it never imports
vnhc_gym, numba or sympy, and takes a few seconds.
"""

from __future__ import annotations

import importlib.util
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
DOCS = REPO / "docs"

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
