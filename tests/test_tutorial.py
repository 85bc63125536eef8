"""The new-task tutorial (docs/new_task.md) runs as written: its task module is saved as a file and
its other code blocks run in order in a fresh process, as a reader would."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

DOC = Path(__file__).resolve().parent.parent / "docs" / "new_task.md"


def _blocks() -> list[str]:
    return re.findall(r"```python\n(.*?)```", DOC.read_text(), re.S)


def test_the_tutorial_has_a_task_module_and_steps() -> None:
    blocks = _blocks()
    assert sum(b.startswith("# puck_task.py") for b in blocks) == 1
    assert len(blocks) >= 5


def test_the_tutorials_task_is_at_most_80_lines_besides_its_card() -> None:
    module = next(b for b in _blocks() if b.startswith("# puck_task.py"))
    card = re.search(r'class PuckSwirlEnv\(ConstraintEnv\):\n    """.*?"""\n', module, re.S)
    assert card is not None
    lines = [line for line in module.replace(card.group(0), "").splitlines() if line.strip()]
    assert len(lines) <= 80, len(lines)


@pytest.mark.slow
def test_the_tutorial_runs(tmp_path: Path) -> None:
    blocks = _blocks()
    module = next(b for b in blocks if b.startswith("# puck_task.py"))
    (tmp_path / "puck_task.py").write_text(module)
    script = "\n".join(b for b in blocks if not b.startswith("# puck_task.py"))
    (tmp_path / "tutorial.py").write_text(script)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), os.environ.get("PYTHONPATH", "")]),
           "MPLBACKEND": "Agg"}
    proc = subprocess.run([sys.executable, "tutorial.py"], cwd=tmp_path, env=env, capture_output=True, text=True,
                          timeout=900)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-4000:]
    assert (tmp_path / "runs" / "puck").exists()
