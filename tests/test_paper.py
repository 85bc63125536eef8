"""The paper-reproduction entry points write every Section IV figure (quick mode)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from vnhc_gym import paper

REPO = Path(__file__).resolve().parents[1]
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
EXPECTED = {
    "flocking_trajectories.png", "flocking_phi3d.png",
    "usv_northeast_trajectory.png", "usv_northeast_phi.png", "usv_northeast_energy.png",
    "usv_anticyclone_trajectory.png", "usv_anticyclone_phi.png", "usv_anticyclone_energy.png",
    "usv_printed_law_failure.png",
}


def _check_pngs(folder: Path) -> None:
    written = {p.name for p in folder.glob("*.png")}
    assert written == EXPECTED
    for name in EXPECTED:
        data = (folder / name).read_bytes()
        assert len(data) > 5000, name  # a real figure, not an empty canvas
        assert data.startswith(PNG_MAGIC), name


def test_cli_reproduce_quick(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from vnhc_gym.cli import main

    out = tmp_path / "figs"
    assert main(["reproduce", "--quick", "--out", str(out)]) == 0
    _check_pngs(out)
    printed = capsys.readouterr().out
    assert all(name in printed for name in EXPECTED)
    assert [Path(line).name for line in printed.splitlines() if line.endswith(".png")] == list(paper.FIGURES)


def test_figure_list_is_complete() -> None:
    assert set(paper.FIGURES) == EXPECTED and len(paper.FIGURES) == len(EXPECTED)


def test_script_quick(tmp_path: Path) -> None:
    out = tmp_path / "script"
    proc = subprocess.run([sys.executable, str(REPO / "experiments" / "reproduce_paper.py"), "--quick", "--out",
                           str(out)], capture_output=True, text=True, timeout=600, cwd=tmp_path,
                          env={**os.environ, "MPLBACKEND": "Agg"})
    assert proc.returncode == 0, proc.stderr
    _check_pngs(out)


def test_help(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as info:
        paper.main(["--help"])
    assert info.value.code == 0
    out = capsys.readouterr().out
    assert "--out" in out and "--quick" in out and "2%" in out


def test_default_arguments() -> None:
    import argparse

    parser = argparse.ArgumentParser()
    paper.add_arguments(parser)
    args = parser.parse_args([])
    assert args.out == "results/paper" and args.quick is False
    assert parser.parse_args(["--quick", "--out", "x"]).quick is True


def test_off_manifold_state_shifts_phi_by_offset() -> None:
    from vnhc_gym.systems import USV_PRESETS, make_usv

    for case in ("paper-northeast", "paper-anticyclone"):
        preset = USV_PRESETS[case]
        model = make_usv(preset.current)
        phi0 = model.phi(preset.state(), preset.params())[0]
        shifted = paper.off_manifold_state(case, 0.3)
        assert model.phi(shifted, preset.params())[0] == pytest.approx(phi0 + 0.3, abs=1e-12)
        np.testing.assert_array_equal(shifted[:3], preset.state()[:3])


@pytest.mark.parametrize("case, phi_20", [("paper-northeast", -0.24), ("paper-anticyclone", -0.63)])
def test_printed_law_in_figure_reproduces_erratum(case: str, phi_20: float) -> None:
    """NOTES.md erratum 2: as printed, phi stays near -0.24 (north-east) / -0.63 (anticyclone) after 20 s."""
    from vnhc_gym.systems import USV_PRESETS, make_usv

    preset = USV_PRESETS[case]
    model = make_usv(preset.current)
    params = preset.params()
    traj = paper._rk4_with_law(model, paper.off_manifold_state(case), params, 0.01, 2000)
    phi = model.phi(traj, params)[:, 0]
    assert phi[-1] == pytest.approx(phi_20, abs=0.01)
    assert np.min(np.abs(phi[-500:])) > 0.1
