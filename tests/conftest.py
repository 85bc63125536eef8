"""Shared fixtures of the environment tests: the registered ids, scenarios, exact comparisons.

Every environment list comes from the task registry (:func:`vnhc_gym.tasks.env_ids`), so a task
added to :mod:`vnhc_gym.tasks` is covered by every parametrised test without new test code.  The
tutorial's task (``docs/new_task.md``) is registered here first, from the page's own code, so it is
held to every registry-wide environment test too (the tests of shipped results, such as tuned
settings and agents, take ``shipped_only``).
"""

from __future__ import annotations

import os

# Rendering must work headless; SDL reads these when pygame first initialises a display or audio.
os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
os.environ.setdefault("SDL_AUDIODRIVER", "dummy")
# One JAX compilation cache for the whole run, shared by the xdist workers and the subprocesses the
# tests start (JAX reads these variables at import): the tests compile the same programs in many
# processes, and a cache that starts empty with the run cut the environment tests' time from 478 s
# to 179 s.  The package itself never sets it (importing vnhc_gym leaves JAX's settings alone).
# Most of the tests' time is XLA compiling small programs that then run a few steps: LLVM's
# optimisation passes cost more there than they save (tests/test_functional_env.py took 148 s instead
# of 214 s without them, and the compiled trainers' tests the same time either way).  The level moves
# results in their last bits only (the Kalman filter's float64 scores over 5 s episodes by about 2e-10
# relative); a test that compares with a number computed at the default level allows for that.
if "xla_backend_optimization_level" not in os.environ.get("XLA_FLAGS", ""):
    os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " --xla_backend_optimization_level=0").strip()
if "JAX_COMPILATION_CACHE_DIR" not in os.environ:
    import tempfile as _tempfile

    os.environ["JAX_COMPILATION_CACHE_DIR"] = _OWN_JAX_CACHE = _tempfile.mkdtemp(prefix="vnhc_gym_test_jax_cache_")
    os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")
else:
    _OWN_JAX_CACHE = None

import re  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
from collections.abc import Callable, Iterator  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from vnhc_gym.envs.config import SCENARIOS  # noqa: E402
from vnhc_gym.tasks import TASKS, env_ids, register_task  # noqa: E402

TUTORIAL = Path(__file__).resolve().parent.parent / "docs" / "new_task.md"
TUTORIAL_TASK = "puck"


def _register_tutorial_task() -> None:
    """Save the tutorial's task module (its ``# puck_task.py`` block) where Python finds it and
    register it as the tutorial does."""
    if TUTORIAL_TASK in TASKS:
        return
    block = next(b for b in re.findall(r"```python\n(.*?)```", TUTORIAL.read_text(), re.S)
                 if b.startswith("# puck_task.py"))
    where = Path(tempfile.mkdtemp(prefix="vnhc_gym_tutorial_"))
    (where / "puck_task.py").write_text(block)
    sys.path.insert(0, str(where))
    register_task(TUTORIAL_TASK, "PuckSwirl", "puck_task")


_register_tutorial_task()


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """The long tests first: a module held to one xdist worker (its whole ``xdist_group``) and the
    tests marked ``slow`` are the largest units of work, and the workers share the many short tests
    best when those come last (in file order, a long unit that starts last keeps one worker busy
    after the other has run out of tests)."""
    def rank(item: pytest.Item) -> int:
        return 0 if item.get_closest_marker("xdist_group") else 1 if item.get_closest_marker("slow") else 2

    items.sort(key=rank)  # stable: each rank keeps the collection order


@pytest.fixture(autouse=True, scope="module")
def _release_compiled_programs() -> Iterator[None]:
    """Each test module's compiled programs are released when it ends (the persistent cache keeps
    them on disk for the next module that needs one): a worker that had compiled most of the suite
    crashed with a segmentation fault inside XLA, in its compiler or in its executable's
    serialisation, on a program it compiled late in its life, where a fresh process compiles the
    same program without fault."""
    yield
    import jax

    jax.clear_caches()


def pytest_unconfigure(config: pytest.Config) -> None:
    """The run's compilation cache goes with the run (removed by the process that made it; the xdist
    workers inherit its path and leave it)."""
    if _OWN_JAX_CACHE is not None and not hasattr(config, "workerinput"):
        import shutil

        shutil.rmtree(_OWN_JAX_CACHE, ignore_errors=True)


def short_id(env_id: str) -> str:
    """``"vnhc_gym/USVStream-v1"`` -> ``"USVStream-v1"`` (test ids)."""
    return env_id.removeprefix("vnhc_gym/")


@pytest.fixture(params=env_ids("v1"), ids=short_id)
def v1_id(request: pytest.FixtureRequest) -> str:
    """Every registered ``-v1`` id (bounded reward, the default)."""
    return request.param


@pytest.fixture(params=env_ids("v0"), ids=short_id)
def v0_id(request: pytest.FixtureRequest) -> str:
    """Every registered ``-v0`` id (raw reward)."""
    return request.param


@pytest.fixture(params=env_ids(None), ids=short_id)
def any_id(request: pytest.FixtureRequest) -> str:
    """Every registered id, of every version."""
    return request.param


@pytest.fixture(params=sorted(SCENARIOS))
def scenario(request: pytest.FixtureRequest) -> str:
    """Every scenario of :data:`vnhc_gym.envs.config.SCENARIOS`."""
    return request.param


#: The (id, scenario) pairs of the scenario-wide tests: every scenario on each ``-v1`` id, and each
#: ``-v0`` id on the nominal scenario (a ``-v0`` id runs its ``-v1`` id's episodes with the raw reward,
#: a function of phi alone, so the scenarios add nothing there that the ``-v1`` ids do not test).
ID_SCENARIOS = [(i, s) for i in env_ids("v1") for s in sorted(SCENARIOS)] + [(i, "nominal") for i in env_ids("v0")]


@pytest.fixture(params=ID_SCENARIOS, ids=lambda pair: f"{short_id(pair[0])}-{pair[1]}")
def id_scenario(request: pytest.FixtureRequest) -> tuple[str, str]:
    """One pair of `ID_SCENARIOS`: an id and a scenario to make it with."""
    return request.param


def _assert_same(a: Any, b: Any, path: str = "") -> None:
    """``a`` and ``b`` are the same to the last bit: same container structure, array dtypes and
    shapes, equal bytes (so NaN payloads and the sign of zero count), equal Python scalars."""
    where = path or "value"
    if isinstance(a, dict):
        assert isinstance(b, dict), f"{where}: dict vs {type(b).__name__}"
        assert set(a) == set(b), f"{where}: keys {sorted(a)} vs {sorted(b)}"
        for key in a:
            _assert_same(a[key], b[key], f"{path}[{key!r}]")
    elif isinstance(a, list | tuple):
        assert type(a) is type(b) and len(a) == len(b), f"{where}: {type(a).__name__}[{len(a)}] vs {b!r}"
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            _assert_same(x, y, f"{path}[{i}]")
    elif isinstance(a, np.ndarray):
        assert isinstance(b, np.ndarray), f"{where}: ndarray vs {type(b).__name__}"
        assert a.dtype == b.dtype and a.shape == b.shape, f"{where}: {a.dtype}{a.shape} vs {b.dtype}{b.shape}"
        if a.dtype == object:
            for i, (x, y) in enumerate(zip(a.ravel(), b.ravel(), strict=True)):
                _assert_same(x, y, f"{path}[{i}]")
        else:
            assert a.tobytes() == b.tobytes(), f"{where}: {a!r} vs {b!r}"
    else:
        assert type(a) is type(b), f"{where}: {type(a).__name__} vs {type(b).__name__}"
        if isinstance(a, float | complex | np.generic):  # by bits: NaN == NaN, -0.0 != 0.0
            assert np.asarray(a).tobytes() == np.asarray(b).tobytes(), f"{where}: {a!r} vs {b!r}"
        else:
            assert a == b, f"{where}: {a!r} vs {b!r}"


@pytest.fixture(scope="session")
def assert_same() -> Callable[[Any, Any], None]:
    """``assert_same(a, b)``: nested results (step tuples, infos, ...) equal bit for bit."""
    return _assert_same


@pytest.fixture(scope="module")
def env_cache() -> Iterator[Callable[..., gym.Env]]:
    """``env_cache(env_id, **kwargs)``: one ``gym.make`` environment per (id, arguments), shared
    by the tests of a module (reset it with a seed before use; do not change its settings)."""
    made: dict[tuple[str, str], gym.Env] = {}

    def get(env_id: str, **kwargs: Any) -> gym.Env:
        key = (env_id, repr(sorted(kwargs.items())))
        if key not in made:
            made[key] = gym.make(env_id, **kwargs)
        return made[key]

    yield get
    for env in made.values():
        env.close()
