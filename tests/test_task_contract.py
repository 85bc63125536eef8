"""What a task author writes, held to its contract: options declared once and checked by name,
termination reasons by name, and short functions."""

from __future__ import annotations

import ast
import inspect
import re
from dataclasses import dataclass, fields
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

from vnhc_gym.envs.config import TaskOptions, check_choice, configure, option
from vnhc_gym.tasks import TASKS, shipped_tasks
from vnhc_gym.tasks.base import Task

TASK_DIR = Path(__file__).resolve().parent.parent / "vnhc_gym" / "tasks"
MAX_HOOK_LINES = 25


# --------------------------------------------------------------------------- options, declared once
def _card_arguments(env_class: type) -> dict[str, str]:
    """The card's Arguments table: argument name -> default cell."""
    card = inspect.getdoc(env_class) or ""
    section = card.split("## Arguments", 1)[1].split("\n## ", 1)[0]
    rows = {}
    for line in section.splitlines():
        m = re.match(r"\|\s*``(\w+)``\s*\|\s*([^|]*?)\s*\|", line.strip())
        if m:
            rows[m.group(1)] = m.group(2)
    return rows


@pytest.mark.parametrize("name", sorted(TASKS))
def test_every_option_is_in_the_card_with_its_default(name: str) -> None:
    """The card's Arguments table has a row for each field of the task's options, showing the
    field's default; and every option has a meaning."""
    entry = TASKS[name]
    rows = _card_arguments(entry.env_class)
    options = entry.task_class.Options
    assert issubclass(options, TaskOptions)
    for f in fields(options):
        assert f.name in rows, f"{name}: the card has no row for option {f.name!r}"
        default = f.default
        shown = rows[f.name].strip('"')
        assert shown == str(default) or shown == repr(default).strip("'"), \
            f"{name}: the card shows {rows[f.name]!r} for {f.name!r}, whose default is {default!r}"
        assert options.docs()[f.name], f"{name}: option {f.name!r} has no meaning"


@pytest.mark.parametrize("name", sorted(TASKS))
def test_options_reach_the_task_unchanged_and_checked(name: str) -> None:
    """``configure`` gives the task every default, and an out-of-range value of any bounded
    numeric option is refused with its name in the message."""
    options = TASKS[name].task_class.Options
    _, got = configure("nominal", {}, options)
    assert got == options().checked()
    for f in fields(options):
        check = f.metadata.get("check")
        if check is None or check["kind"] != "number" or check["low"] is None:
            continue
        with pytest.raises(ValueError, match=rf"^{f.name} must be"):
            configure("nominal", {f.name: check["low"] - 1.0}, options)


def test_task_options_checks_by_kind() -> None:
    @dataclass(frozen=True)
    class Opts(TaskOptions):
        width: float = option(1.0, "width (m)", low=0.0, low_open=True)
        count: int = option(3, "how many", integer=True, low=1, high=5)
        mode: str = option("a", "which", choices=("a", "b"))
        note: object = option(None, "free: the task checks it")

    assert Opts(width=2).checked().width == 2.0 and isinstance(Opts(width=2).checked().width, float)
    with pytest.raises(ValueError, match=r"^width must be a finite number > 0"):
        Opts(width=0.0).checked()
    with pytest.raises(TypeError, match=r"^width must be"):
        Opts(width="wide").checked()  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r"^count must be an integer >= 1 and <= 5"):
        Opts(count=6).checked()
    with pytest.raises(ValueError, match=r"^mode must be one of \['a', 'b'\], got 'c'"):
        Opts(mode="c").checked()
    assert Opts(note=[1, 2]).checked().note == [1, 2]
    assert Opts.defaults() == {"width": 1.0, "count": 3, "mode": "a", "note": None}
    assert check_choice("preset", None, ("x",), allow_none=True) is None
    with pytest.raises(ValueError, match=r"or None, got 'y'"):
        check_choice("preset", "y", ("x",), allow_none=True)


# --------------------------------------------------------------------------- reasons, stages, bounds
@pytest.mark.parametrize("reasons", [{"a": 1}, ("a", "a"), ("a", 1), ("non_finite_state",), ("",), ["a"]])
def test_inconsistent_task_declarations_are_refused(reasons: object) -> None:
    cls = type("BadTask", (Task,), {"reasons": reasons})
    with pytest.raises(ValueError, match="BadTask"):
        cls.check_definition()


@pytest.mark.parametrize("name", sorted(TASKS))
def test_termination_reasons_are_named_by_status(name: str) -> None:
    """``all_reasons`` holds no termination, then ``non_finite_state``, the declared reasons in
    order, then the reasons only ``limits`` name, each once."""
    cls = TASKS[name].task_class
    cls.check_definition()
    env = gym.make(f"vnhc_gym/{TASKS[name].env_name}-v1")
    task = env.unwrapped.task
    table = task.all_reasons
    assert table[:2 + len(cls.reasons)] == (None, "non_finite_state", *cls.reasons)
    assert set(table[2:]) == set(cls.reasons) | {reason for reason, _, _ in task.limits}
    assert len(set(table)) == len(table)
    env.close()


@pytest.mark.parametrize("name", sorted(TASKS))
def test_force_bounds_are_per_control_with_units(name: str) -> None:
    """The default bound has one entry per control; ``force_bound`` sets all of them; the scale
    multiplies; the units name every control."""
    env_id = f"vnhc_gym/{TASKS[name].env_name}-v1"
    task = gym.make(env_id).unwrapped.task
    default = np.broadcast_to(np.asarray(type(task).default_force_bound, dtype=float), (task.act_dim,))
    np.testing.assert_array_equal(task.force_bound, default)
    assert len(task.units) == task.act_dim and all(task.units)
    one = gym.make(env_id, force_bound=7.0).unwrapped.task
    np.testing.assert_array_equal(one.force_bound, np.full(task.act_dim, 7.0))
    np.testing.assert_array_equal(gym.make(env_id, scenario="saturated").unwrapped.task.force_bound, default * 0.05)


# --------------------------------------------------------------------------- short hooks
def _function_lengths(path: Path) -> dict[str, int]:
    """Lines of code (without the docstring) of every function and method of a module."""
    tree = ast.parse(path.read_text())
    out = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.FunctionDef):
            body = node.body
            if body and isinstance(body[0], ast.Expr) and isinstance(getattr(body[0], "value", None), ast.Constant):
                body = body[1:]
            if body:
                out[node.name] = body[-1].end_lineno - body[0].lineno + 1  # type: ignore[operator]
    return out


@pytest.mark.parametrize("name", sorted(shipped_tasks()))
def test_task_hooks_are_short(name: str) -> None:
    """The per-row hooks and the task's methods stay short: the common work is the package's."""
    path = Path(inspect.getfile(TASKS[name].load()))
    long = {f: n for f, n in _function_lengths(path).items() if n > MAX_HOOK_LINES and not f.startswith("_render")}
    # The constructor may validate its options at length, but not beyond twice the hooks' limit.
    if long.get("__init__", 0) <= 2 * MAX_HOOK_LINES:
        long.pop("__init__", None)
    assert not long, f"{path.name}: {long}"


def test_tutorial_task_module_is_short() -> None:
    """The tutorial's task is at most 80 lines of code besides its docstrings (the card among them)."""
    from conftest import TUTORIAL

    block = next(b for b in re.findall(r"```python\n(.*?)```", TUTORIAL.read_text(), re.S)
                 if b.startswith("# puck_task.py"))
    tree = ast.parse(block)
    docstrings: set[int] = set()
    for node in ast.walk(tree):
        body = getattr(node, "body", None)
        if isinstance(body, list) and body and isinstance(body[0], ast.Expr) \
                and isinstance(body[0].value, ast.Constant) and isinstance(body[0].value.value, str):
            docstrings |= set(range(body[0].lineno, body[0].end_lineno + 1))  # type: ignore[operator]
    code = [ln for i, ln in enumerate(block.splitlines(), 1)
            if i not in docstrings and ln.strip() and not ln.strip().startswith("#")]
    assert len(docstrings) > 20, "the card is a docstring"
    assert len(code) <= 80, len(code)


# --------------------------------------------------------------------------- layers
PACKAGE = TASK_DIR.parent


def _runtime_imports(path: Path) -> set[str]:
    """The ``vnhc_gym`` modules a file imports when it runs (anywhere in it, functions included;
    not under ``if TYPE_CHECKING``, which only type checkers read)."""
    tree = ast.parse(path.read_text())
    typing_only = {id(n) for node in ast.walk(tree) if isinstance(node, ast.If)
                   and isinstance(node.test, ast.Name) and node.test.id == "TYPE_CHECKING"
                   for n in ast.walk(node)}
    found = set()
    for node in ast.walk(tree):
        if id(node) in typing_only:
            continue
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.add(node.module)
        elif isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
    return {m for m in found if m.startswith("vnhc_gym")}


@pytest.mark.parametrize(("layer", "forbidden"), [
    ("mechanics", ("vnhc_gym.envs", "vnhc_gym.tasks", "vnhc_gym.systems")),
    ("systems", ("vnhc_gym.envs", "vnhc_gym.tasks")),
    ("envs", ("vnhc_gym.tasks",)),
    ("tasks", ("vnhc_gym.envs.runtime",)),  # a task is pure functions: the batch that runs them is not its business
])
def test_a_layer_never_imports_the_layers_above_it(layer: str, forbidden: tuple[str, ...]) -> None:
    """The math knows nothing of environments or tasks, the environments nothing of the task
    registry, and a task nothing of the batch that runs it: every import points down, so none needs
    to hide inside a function to break a cycle."""
    bad = {f"{path.relative_to(PACKAGE)}: {m}" for path in sorted((PACKAGE / layer).rglob("*.py"))
           for m in _runtime_imports(path) if m.startswith(forbidden)}
    assert not bad, sorted(bad)
    assert _runtime_imports(PACKAGE / "envs" / "runtime.py"), "the parser sees the package's imports"


def test_a_task_without_a_scene_has_no_render_modes() -> None:
    """`ConstraintEnv` reads from the task whether it draws: a task class that keeps `Task.scene`
    gets an environment with no render modes, and one that defines a scene gets both."""
    from vnhc_gym.envs import ConstraintEnv

    drawn = TASKS["usv"].task_class
    plain = type("PlainTask", (drawn,), {"scene": Task.scene})
    assert drawn.draws() and not plain.draws()
    plain_env = type("PlainEnv", (ConstraintEnv,), {"task_class": plain})
    drawn_env = type("DrawnEnv", (ConstraintEnv,), {"task_class": drawn})
    assert plain_env.metadata["render_modes"] == []
    assert set(drawn_env.metadata["render_modes"]) == {"human", "rgb_array"}
