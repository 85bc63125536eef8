"""Rewrite the generated modules the package ships: ``python -m vnhc_gym.mechanics.ship``.

A cache miss copies a shipped module instead of generating it (see `vnhc_gym.mechanics.cache`), so
a user's first run of any built-in environment only compiles.  Each module's name is a hash of the
sources it is made from, so after an edit of a system, a task or the code generator the shipped
copies no longer match and the package generates again; this command brings them up to date (the
tests fail until it has run).  It generates only what the local cache does not hold.
"""

from __future__ import annotations

import shutil
import sys
import warnings

from vnhc_gym.mechanics import cache

__all__ = ["build_built_in", "main"]


def build_built_in() -> list[str]:
    """Build every registered environment in every scenario, and the USV in every named current.

    Returns
    -------
    list of str
        The keys of the generated modules they load (sorted).
    """
    import gymnasium as gym

    import vnhc_gym  # noqa: F401 - registers the environments
    from vnhc_gym.envs.config import SCENARIOS
    from vnhc_gym.systems.currents import CURRENTS
    from vnhc_gym.systems.usv import make_usv

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the v0 ids' out-of-date notice
        for env_id in sorted(k for k in gym.registry if k.startswith("vnhc_gym/")):
            for scenario in SCENARIOS:
                gym.make(env_id, scenario=scenario).close()
    for current in CURRENTS:
        make_usv(current)
    return sorted(cache._LOADED)


def main() -> int:
    """Write the modules of `build_built_in` into `cache.SHIPPED_DIR` and remove any other."""
    keys = build_built_in()
    folder = cache.cache_dir()
    cache.SHIPPED_DIR.mkdir(exist_ok=True)
    wanted = {f"vnhc_gen_{key}.py" for key in keys}
    for name in sorted(wanted):
        shutil.copyfile(folder / name, cache.SHIPPED_DIR / name)
    stale = [p for p in cache.SHIPPED_DIR.glob("vnhc_gen_*.py") if p.name not in wanted]
    for path in stale:
        path.unlink()
    size = sum((cache.SHIPPED_DIR / n).stat().st_size for n in wanted)
    print(f"{cache.SHIPPED_DIR}: {len(wanted)} modules ({size / 1e6:.1f} MB), {len(stale)} stale removed",
          file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
