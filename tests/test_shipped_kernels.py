"""The generated modules the package ships: a cold cache copies them instead of generating (no
sympy), each is exactly what generation writes, a damaged copy is never used, and the folder holds
the modules of every built-in environment and no other."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from vnhc_gym.mechanics import cache
from vnhc_gym.mechanics.cache import SHIPPED_DIR, shipped_source
from vnhc_gym.systems import make_sled, make_usv

STATE = [0.4, -1.3, 0.7, 0.8, -0.5, 0.3]  # (x, y, theta, xd, yd, thetad)

_COLD_USV = textwrap.dedent(f"""
    import json, sys
    import numpy as np
    from vnhc_gym.systems import make_usv

    model = make_usv("northeast")
    print(json.dumps({{"phi": model.phi(np.array({STATE!r})).tolist(), "sympy": "sympy" in sys.modules,
                      "file": model.compiled.__file__, "key": model._key}}))
""")


def test_a_cold_cache_copies_the_shipped_module_without_sympy(tmp_path: Path) -> None:
    """A first run on an empty cache neither imports sympy nor generates: it copies the shipped text,
    and the kernel gives the hand-derived phi of the USV in the current (1, 1)."""
    env = {**os.environ, "VNHC_GYM_CACHE_DIR": str(tmp_path / "cache"), "NUMBA_CACHE_DIR": str(tmp_path / "numba")}
    proc = subprocess.run([sys.executable, "-c", _COLD_USV], env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    assert not out["sympy"]
    x, y, th, xd, yd, thd = STATE
    np.testing.assert_allclose(out["phi"], [np.sin(th) * (xd - 1.0) - np.cos(th) * (yd - 1.0)], rtol=1e-14)
    copied = Path(out["file"]).read_text(encoding="utf-8").partition("\n")[2]
    assert copied == shipped_source(out["key"])


@pytest.mark.parametrize("make", [lambda: make_usv("northeast"), make_sled], ids=["usv-northeast", "sled"])
def test_a_shipped_module_is_what_generation_writes(make) -> None:  # type: ignore[no-untyped-def]
    """Generation is deterministic: the shipped text equals a fresh generation from the symbolic system."""
    model = make()
    shipped = shipped_source(model._key)
    assert shipped is not None, "not shipped: run python -m vnhc_gym.mechanics.ship"
    assert model._make_source() == shipped


def test_a_damaged_shipped_copy_is_not_used(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    source = "N = 1\n"
    good = cache._HEADER + cache._digest(source) + "\n" + source
    monkeypatch.setattr(cache, "SHIPPED_DIR", tmp_path)
    (tmp_path / "vnhc_gen_good.py").write_text(good, encoding="utf-8")
    (tmp_path / "vnhc_gen_edited.py").write_text(good.replace("N = 1", "N = 2"), encoding="utf-8")
    (tmp_path / "vnhc_gen_truncated.py").write_text(good[:20], encoding="utf-8")
    assert shipped_source("good") == source
    assert shipped_source("edited") is None
    assert shipped_source("truncated") is None
    assert shipped_source("missing") is None


def test_the_shipped_folder_holds_exactly_the_built_in_modules() -> None:
    """Every environment in every scenario, and the USV in every current, finds its modules shipped,
    and nothing else is shipped (a fresh process, so other tests' systems do not count)."""
    code = "import json; from vnhc_gym.mechanics.ship import build_built_in; print(json.dumps(build_built_in()))"
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=1800)
    assert proc.returncode == 0, proc.stderr
    used = {f"vnhc_gen_{key}.py" for key in json.loads(proc.stdout.strip().splitlines()[-1])}
    shipped = {p.name for p in SHIPPED_DIR.glob("vnhc_gen_*.py")}
    hint = "run python -m vnhc_gym.mechanics.ship"
    assert used <= shipped, f"not shipped: {sorted(used - shipped)}; {hint}"
    assert shipped <= used, f"stale: {sorted(shipped - used)}; {hint}"
