"""The on-disk kernel cache, seen from fresh processes: warm starts without sympy, damaged entries
rebuilt with one warning, unusable folders replaced by a fallback, concurrent cold starts, and the
one-line notice of a first compile.

Every run is a new interpreter (``subprocess``), so the in-process caches of loaded modules and
resolved folders play no part.  The compiled system is the USV in the north-east current (small and
quick to compile); one cold cache is built per module and copied for each test.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from vnhc_gym.mechanics.cache import LAYOUT_VERSION

LAYOUT = f"layout-{LAYOUT_VERSION}"
NOTICE = "vnhc_gym: compiling kernels for "
STATE = [0.4, -1.3, 0.7, 0.8, -0.5, 0.3]  # (x, y, theta, xd, yd, thetad)

# The USV in the current (1, 1), m = 10: phi and u* = C^-1 (-k phi - G) with k = 2, by hand.
_RUN_USV = textwrap.dedent(f"""
    import json, sys, warnings
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        import numpy as np
        from vnhc_gym.systems import make_usv

        model = make_usv("northeast")
        s = np.array({STATE!r})
        phi = model.phi(s).tolist()
        u = model.control(s, gains=2.0).tolist()
    print(json.dumps({{"phi": phi, "u": u, "file": model.compiled.__file__,
                      "warnings": [[w.category.__name__, str(w.message)] for w in caught]}}))
""")

_WARM_START = textwrap.dedent("""
    import json, pickle, sys
    import numpy as np
    from vnhc_gym.systems import make_flocking, make_usv

    out = {}
    f = make_flocking(3)
    u = make_usv("northeast")
    out["phi_flocking"] = f.phi(np.arange(12.0)).tolist()
    out["phi_usv"] = u.phi(np.arange(6.0)).tolist()
    out["sympy_after_phi"] = "sympy" in sys.modules
    blobs = [pickle.dumps(u), pickle.dumps(f)]
    out["sympy_in_pickle"] = any(b"sympy" in blob for blob in blobs)
    u2, f2 = (pickle.loads(blob) for blob in blobs)
    out["phi_unpickled"] = [u2.phi(np.arange(6.0)).tolist(), f2.phi(np.arange(12.0)).tolist()]
    out["params"] = u2.params(m=3.0).tolist()
    out["sympy_after_pickle"] = "sympy" in sys.modules
    out["system_name"] = f2.system.name  # lazy: builds the symbolic side now
    out["sympy_after_system"] = "sympy" in sys.modules
    print(json.dumps(out))
""")


def _hand_usv() -> tuple[float, float]:
    x, y, th, xd, yd, thd = STATE
    phi = np.sin(th) * (xd - 1.0) - np.cos(th) * (yd - 1.0)
    return phi, -10.0 * (2.0 * phi + thd * (xd * np.cos(th) + yd * np.sin(th)))


def _env(cache: Path | str, **extra: str) -> dict[str, str]:
    env = {**os.environ, "VNHC_GYM_CACHE_DIR": str(cache)}
    env.pop("NUMBA_CACHE_DIR", None)  # numba's machine code beside the generated module (unless extra says)
    return {**env, **extra}


def _run(script: str, env: dict[str, str], check: bool = True) -> tuple[dict, str]:
    proc = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=600,
                          check=False)
    if check:
        assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout.strip().splitlines()[-1]) if proc.returncode == 0 else {}
    return out, proc.stderr


def _check_usv(out: dict) -> None:
    phi, u = _hand_usv()
    np.testing.assert_allclose(out["phi"], [phi], rtol=1e-13)
    np.testing.assert_allclose(out["u"], [u], rtol=1e-12)


def _entry(folder: Path) -> Path:
    """The USV's generated module (the pristine cache also holds the flocking ones)."""
    (path,) = [p for p in folder.glob("vnhc_gen_*.py") if "system 'usv_northeast'" in p.read_text(encoding="utf-8")]
    return path


def _checksum_ok(path: Path) -> bool:
    head, _, body = path.read_text(encoding="utf-8").partition("\n")
    return head.endswith(hashlib.sha256(body.encode()).hexdigest())


def _cache_warnings(out: dict) -> list[str]:
    return [message for category, message in out["warnings"] if category == "CacheWarning"]


@pytest.fixture(scope="module")
def pristine(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    """A cache built by one cold start of the USV script (then the flocking warm-start script), and
    the cold start's stderr."""
    root = tmp_path_factory.mktemp("pristine")
    out, stderr = _run(_RUN_USV, _env(root))
    _check_usv(out)
    assert not out["warnings"]
    _run(_WARM_START, _env(root))
    return root, stderr


@pytest.fixture
def cache(pristine: tuple[Path, str], tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A copy of the pristine cache, named by VNHC_GYM_CACHE_DIR for this test; returns its layout folder."""
    root = tmp_path / "cache"
    shutil.copytree(pristine[0], root)
    monkeypatch.setenv("VNHC_GYM_CACHE_DIR", str(root))
    return root / LAYOUT


def test_first_compile_notice_once(pristine: tuple[Path, str], cache: Path) -> None:
    _, cold = pristine
    lines = [line for line in cold.splitlines() if line.startswith(NOTICE)]
    assert lines == [f"{NOTICE}usv/northeast (first use only; cached in {pristine[0] / LAYOUT})"]
    out, warm = _run(_RUN_USV, _env(cache.parent))
    _check_usv(out)
    assert NOTICE not in warm and not out["warnings"]
    assert Path(out["file"]).parent == cache


def test_warm_start_does_not_import_sympy(cache: Path) -> None:
    """With a warm cache, making the shipped systems, evaluating and pickling them never imports sympy."""
    warm, stderr = _run(_WARM_START, _env(cache.parent))
    assert NOTICE not in stderr
    assert not warm["sympy_after_phi"] and not warm["sympy_in_pickle"] and not warm["sympy_after_pickle"]
    assert warm["sympy_after_system"] and warm["system_name"] == "flocking3"
    s = np.arange(12.0)  # q = s[:6], qd = (xd_1..3, zd_1..3) = s[6:]: phi^b = xd_3 zd_b - xd_b zd_3
    xd, zd = s[6:9], s[9:12]
    np.testing.assert_allclose(warm["phi_flocking"], xd[2] * zd[:2] - xd[:2] * zd[2], rtol=1e-14)
    x, y, th, xdu, ydu, _ = np.arange(6.0)
    phi_usv = np.sin(th) * (xdu - 1.0) - np.cos(th) * (ydu - 1.0)
    np.testing.assert_allclose(warm["phi_usv"], [phi_usv], rtol=1e-13)
    assert warm["phi_unpickled"] == [warm["phi_usv"], warm["phi_flocking"]]
    assert warm["params"] == [3.0, 1.5, 1.0, 1.0, 1.0]


@pytest.mark.slow
@pytest.mark.parametrize("damage", ["truncated", "emptied"])
def test_damaged_generated_module_is_rebuilt(cache: Path, damage: str) -> None:
    path = _entry(cache)
    text = path.read_text(encoding="utf-8")
    path.write_text(text[:len(text) // 2] if damage == "truncated" else "", encoding="utf-8")
    out, _ = _run(_RUN_USV, _env(cache.parent))
    _check_usv(out)
    (message,) = _cache_warnings(out)
    assert not [w for w in out["warnings"] if w[0] != "CacheWarning"]
    assert "rebuilding the damaged kernel cache entry" in message and path.name in message
    assert path.read_text(encoding="utf-8") == text and _checksum_ok(path)
    out, _ = _run(_RUN_USV, _env(cache.parent))  # and the next start is clean
    _check_usv(out)
    assert not out["warnings"]


def _damage_machine_code(cache: Path, suffix: str) -> list[Path]:
    files = sorted((cache / "__pycache__").glob(f"{_entry(cache).stem}.*{suffix}"))
    assert files, f"no {suffix} files in the pristine cache"
    for f in files:
        data = f.read_bytes()
        f.write_bytes(data[:len(data) // 2])
    return files


@pytest.mark.slow
def test_damaged_numba_index_is_recompiled(cache: Path) -> None:
    _damage_machine_code(cache, ".nbi")
    out, _ = _run(_RUN_USV, _env(cache.parent))
    _check_usv(out)
    (message,) = _cache_warnings(out)
    assert "recompiling the damaged machine code" in message
    out, _ = _run(_RUN_USV, _env(cache.parent))
    _check_usv(out)
    assert not out["warnings"]


def test_damaged_numba_data_is_recompiled(cache: Path) -> None:
    _damage_machine_code(cache, ".nbc")
    out, stderr = _run(_RUN_USV, _env(cache.parent), check=False)
    assert out, stderr[-2000:]
    _check_usv(out)
    (message,) = _cache_warnings(out)
    assert "recompiling the damaged machine code" in message


@pytest.mark.parametrize("kind", ["file", "layout file", "read-only"])
def test_unusable_cache_folder_falls_back_with_a_warning(pristine: tuple[Path, str], tmp_path: Path,
                                                         monkeypatch: pytest.MonkeyPatch, kind: str) -> None:
    root = tmp_path / "configured"
    if kind == "file":
        root.write_text("not a folder\n")
    elif kind == "layout file":
        root.mkdir()
        (root / LAYOUT).write_text("not a folder\n")
    else:
        (root / LAYOUT).mkdir(parents=True)
        (root / LAYOUT).chmod(0o555)
        if os.access(root / LAYOUT, os.W_OK):
            (root / LAYOUT).chmod(0o755)
            pytest.skip("running as a user whom chmod does not stop from writing (root)")
    monkeypatch.setenv("VNHC_GYM_CACHE_DIR", str(root))
    # The fallback is a per-user folder in the temporary directory: here one of the test's own, warm.
    temp = tmp_path / "temp"
    fallback = temp / f"vnhc_gym-{os.getuid()}" / LAYOUT
    shutil.copytree(pristine[0] / LAYOUT, fallback)
    try:
        out, _ = _run(_RUN_USV, _env(root, TMPDIR=str(temp)))
    finally:
        if kind == "read-only":
            (root / LAYOUT).chmod(0o755)
    _check_usv(out)
    (message,) = _cache_warnings(out)
    assert "VNHC_GYM_CACHE_DIR" in message and str(root / LAYOUT) in message and str(fallback) in message
    assert Path(out["file"]).parent == fallback
    if kind == "file":
        assert root.read_text() == "not a folder\n"


@pytest.mark.slow
def test_concurrent_cold_starts_both_succeed(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    root = tmp_path / "cold"
    monkeypatch.setenv("VNHC_GYM_CACHE_DIR", str(root))
    env = _env(root)
    procs = [subprocess.Popen([sys.executable, "-c", _RUN_USV], env=env, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True) for _ in range(2)]
    results = [p.communicate(timeout=600) + (p.returncode,) for p in procs]
    for stdout, stderr, code in results:
        assert code == 0, stderr
        out = json.loads(stdout.strip().splitlines()[-1])
        _check_usv(out)
        assert not out["warnings"]  # a concurrent writer is not damage
    path = _entry(root / LAYOUT)
    assert _checksum_ok(path)
    assert not [p for p in (root / LAYOUT).rglob("*") if ".tmp" in p.name]


@pytest.mark.slow
def test_notice_once_with_numba_cache_dir(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("VNHC_GYM_CACHE_DIR", str(tmp_path / "cache"))
    env = _env(tmp_path / "cache", NUMBA_CACHE_DIR=str(tmp_path / "numba"))
    notices = []
    for _ in range(2):  # the first start compiles into NUMBA_CACHE_DIR, the second is warm
        out, stderr = _run(_RUN_USV, env)
        _check_usv(out)
        notices.append(stderr.count(NOTICE))
    assert list((tmp_path / "numba").rglob("*.nbi")) and not list((tmp_path / "cache").rglob("*.nbi"))
    assert notices == [1, 0]
