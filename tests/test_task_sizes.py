"""A task whose declared sizes disagree with what its hooks write is refused at ``make`` with a
``ValueError`` naming the task and the size, never by a crash.

Each case is the tutorial's task module with one declaration or hook edited, made in a fresh
process: a hook writing past a compiled buffer corrupts memory and can abort the interpreter, which
in a subprocess fails the test instead of killing the test run.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

TUTORIAL = Path(__file__).resolve().parent.parent / "docs" / "new_task.md"

MAKE_ALL = """
import gymnasium as gym
from vnhc_gym.tasks import register_task

register_task("puck_bad", "PuckSwirl", "puck_task")
try:
    env = gym.make("vnhc_gym/PuckSwirl-v1")
    env.reset(seed=0)
    env.step(env.action_space.sample())
    vec = gym.make_vec("vnhc_gym/PuckSwirl-v1", num_envs=3, vectorization_mode="vector_entry_point")
    vec.reset(seed=0)
    vec.step(vec.action_space.sample())
except ValueError as exc:
    print("ValueError:", exc)
else:
    print("made")
"""


def _task_module() -> str:
    return next(b for b in re.findall(r"```python\n(.*?)```", TUTORIAL.read_text(), re.S)
                if b.startswith("# puck_task.py"))


def _make(tmp_path: Path, module: str) -> subprocess.CompletedProcess[str]:
    (tmp_path / "puck_task.py").write_text(module)
    (tmp_path / "make_all.py").write_text(MAKE_ALL)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), os.environ.get("PYTHONPATH", "")])}
    return subprocess.run([sys.executable, "make_all.py"], cwd=tmp_path, env=env, capture_output=True, text=True,
                          timeout=600)


def _edit(module: str, old: str, new: str) -> str:
    if module.count(old) != 1:
        raise LookupError(f"the tutorial's task module no longer holds {old!r} once: update this test's edits")
    return module.replace(old, new)


def test_the_unedited_module_is_made(tmp_path: Path) -> None:
    proc = _make(tmp_path, _task_module())
    assert proc.returncode == 0 and proc.stdout.strip().endswith("made"), proc.stdout + proc.stderr[-3000:]


# (edit, what the error names): each edit makes one declared size wrong.
CASES = {
    "obs_dim smaller than the observation": (("self.obs_dim = 6", "self.obs_dim = 4"),
                                             ["'puck'", "observation returns shape (6,)", "(4,)"]),
    "obs_dim larger than the observation": (("self.obs_dim = 6", "self.obs_dim = 9"),
                                            ["'puck'", "observation returns shape (6,)", "(9,)"]),
    "initial returns more than the state": (("omega * x + off[1]])", "omega * x + off[1], x])"),
                                            ["'puck'", "initial returns shape (5,)", "(4,)"]),
    "terminations that are not the declared reasons": (('{"off_table":', '{"off":'),
                                                        ["'puck'", "terminations", "off_table"]),
    "impulse_mask of the wrong size": (("self.impulse_mask = np.ones(2)", "self.impulse_mask = np.ones(3)"),
                                       ["'puck'", "impulse_mask", "2 velocity entries"]),
    "a controller's state of the wrong size": (("return 2.0 * obs[:4], p", "return 2.0 * obs[:5], p"),
                                               ["'puck'", "controller_inputs (its state) returns shape (5,)", "(4,)"]),
}


@pytest.mark.parametrize("case", list(CASES))
def test_a_wrong_size_raises_at_make_naming_it(case: str, tmp_path: Path) -> None:
    (old, new), named = CASES[case]
    proc = _make(tmp_path, _edit(_task_module(), old, new))
    assert proc.returncode == 0, f"the process crashed (exit {proc.returncode}): {proc.stderr[-3000:]}"
    out = proc.stdout.strip()
    assert out.startswith("ValueError:"), out + proc.stderr[-3000:]
    for text in named:
        assert text in out, (text, out)


def test_an_invalid_constraint_is_refused_at_make_naming_the_symbol(tmp_path: Path) -> None:
    """A constraint with a symbol the system does not know: a ValueError at make that names it."""
    module = _edit(_task_module(), "xd + omega * y, yd - omega * x", "xd + sp.Symbol('kappa') * y, yd - omega * x")
    (tmp_path / "puck_task.py").write_text(module)
    (tmp_path / "make_all.py").write_text(MAKE_ALL)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), os.environ.get("PYTHONPATH", "")])}
    proc = subprocess.run([sys.executable, "make_all.py"], cwd=tmp_path, env=env, capture_output=True, text=True,
                          timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert proc.stdout.startswith("ValueError:") and "kappa" in proc.stdout, proc.stdout + proc.stderr[-3000:]
