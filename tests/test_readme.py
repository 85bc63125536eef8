"""The README as a contract: its quickstart runs as written, in a new process, and every command it
shows exists with the options it uses."""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
README = (ROOT / "README.md").read_text()


def test_the_two_commands_are_there() -> None:
    blocks = re.findall(r"```bash\n(.*?)```", README, re.S)
    assert blocks[0].strip() == 'pip install torch==2.13.0 && pip install -e ".[all]" && vnhc-gym benchmark'
    assert blocks[1].strip() == "python -m pytest -q"


def test_readme_is_a_product_page() -> None:
    assert len(README.splitlines()) <= 200
    for forbidden in ("../shared", "NOTES.md", "ad hoc", "session"):
        assert forbidden not in README


def test_relative_links_exist() -> None:
    for target in re.findall(r"\]\(([^)#]+)(?:#[^)]*)?\)", README):
        if "://" not in target:
            assert (ROOT / target).exists(), target


def test_every_shown_vnhc_gym_command_parses(monkeypatch: pytest.MonkeyPatch) -> None:
    """Each `vnhc-gym ...` command of the README parses with its options: the console script's
    `main` reaches the command with the arguments it was given, its run replaced by a recorder so
    that nothing runs (an option the command does not know exits with status 2 instead; the console
    script itself is run as a process in tests/test_cli.py)."""
    import importlib

    from vnhc_gym import cli

    commands = set(re.findall(r"`(vnhc-gym [^`]+)`", README))
    assert {c.split()[1] for c in commands} >= {"benchmark", "train", "sweep", "reproduce"}
    monkeypatch.setattr(cli, "use_compilation_cache", lambda: None)  # JAX's settings stay the test process's
    reached = []
    for module_name, _ in cli.SUBCOMMANDS.values():
        monkeypatch.setattr(importlib.import_module(module_name), "run", reached.append)
    for command in sorted(commands):
        argv = shlex.split(command)[1:]
        assert cli.main(argv) == 0, command
        assert reached.pop().command == argv[0], command
    with pytest.raises(SystemExit) as stop:  # and the check can fail
        cli.main(["train", "--no-such-option", "3"])
    assert stop.value.code == 2


@pytest.mark.slow
def test_quickstart_runs_as_written(tmp_path: Path) -> None:
    code = re.search(r"## Quickstart\n\n```python\n(.*?)```", README, re.S)
    assert code is not None
    env = {**os.environ, "MPLBACKEND": "Agg"}
    proc = subprocess.run([sys.executable, "-c", code.group(1)], cwd=tmp_path, env=env, capture_output=True,
                          text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr[-4000:]
    assert "final |phi|:" in proc.stdout
