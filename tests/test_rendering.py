"""The planar renderer: frames, robustness, the phi panel, the field quiver, the 3D helper, and the
flock and boat renderers built on it."""

from __future__ import annotations

import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("pygame")

from vnhc_gym.envs.rendering import (  # noqa: E402 - after the skip
    _CURRENT,
    _PHI_BAR,
    _PHI_SATURATED,
    SCREEN_SIZE,
    Body,
    Link,
    PlanarRenderer,
    Scene,
    axes_3d,
    flock_scene,
    hull_scene,
)

NAN, INF, HUGE = math.nan, math.inf, 1e300


@pytest.fixture
def renderer():
    r = PlanarRenderer("rgb_array")
    yield r
    r.close()


def _is_frame(f: object) -> bool:
    return isinstance(f, np.ndarray) and f.shape == (SCREEN_SIZE, SCREEN_SIZE, 3) and f.dtype == np.uint8


def _mask(frame: np.ndarray, color: tuple[int, int, int]) -> np.ndarray:
    return np.all(frame == np.array(color, np.uint8), axis=-1)


def _current(x, y):
    return np.stack([0.5 + 0.0 * x, 0.2 * np.sin(y)], axis=-1)


# --------------------------------------------------------------------------- frames


def test_rgb_array_frame_shape_and_dtype(renderer: PlanarRenderer) -> None:
    assert SCREEN_SIZE == 500
    f = renderer.draw(Scene(bodies=[Body(0.0, 0.0)]))
    assert _is_frame(f)
    assert len(np.unique(f.reshape(-1, 3), axis=0)) > 2  # background, grid, body at least
    assert _is_frame(renderer.draw(Scene()))  # an empty scene is a frame too


def test_moving_one_body_changes_the_frame(renderer: PlanarRenderer) -> None:
    # A fixed camera, so only the body moves.
    def scene(x: float) -> Scene:
        return Scene(bodies=[Body(0.0, 0.0), Body(x, 1.0, heading=0.2, size=1.0)], center=(0.0, 0.0), extent=10.0)

    a, b = renderer.draw(scene(1.0)), renderer.draw(scene(2.0))
    assert not np.array_equal(a, b)
    np.testing.assert_array_equal(a, renderer.draw(scene(1.0)))  # and drawing is deterministic


def test_default_camera_follows_the_bodies(renderer: PlanarRenderer) -> None:
    # The same relative layout far away draws the same bodies; the grid shows the camera moved.
    near = renderer.draw(Scene(bodies=[Body(0.0, 0.0), Body(1.0, 0.3)]))
    far = renderer.draw(Scene(bodies=[Body(1000.3, 7.1), Body(1001.3, 7.4)]))
    body = (52, 101, 164)
    np.testing.assert_array_equal(_mask(near, body), _mask(far, body))
    assert not np.array_equal(near, far)


def test_every_kind_of_item_is_drawn(renderer: PlanarRenderer) -> None:
    base = Scene(bodies=[Body(0.0, 0.0)], center=(0.0, 0.0), extent=10.0)
    blank = renderer.draw(base)
    for extra in ({"links": [((0.0, 0.0), (3.0, 3.0))]}, {"links": [Link((0, 0), (-3, 2), (0, 200, 0), 2, True)]},
                  {"guides": [((-4.0, -1.0), (4.0, -1.0))]}, {"text": ["t = 1.00 s"]},
                  {"bodies": [Body(0.0, 0.0, velocity=(1.0, 0.0), label="a")]}):
        kw = {**base.__dict__, **extra}
        assert not np.array_equal(renderer.draw(Scene(**kw)), blank), extra


# --------------------------------------------------------------------------- robustness


BAD = (NAN, INF, -INF, HUGE, -HUGE)


@pytest.mark.parametrize("bad", BAD)
def test_non_finite_or_huge_numbers_anywhere_never_raise(renderer: PlanarRenderer, bad: float) -> None:
    scene = Scene(
        bodies=[Body(bad, 0.0), Body(0.0, bad), Body(1.0, 1.0, heading=bad, size=bad, velocity=(bad, 1.0)),
                Body(2.0, 0.0, heading=0.0, size=bad, velocity=(1.0, bad), label="b"), Body(0.0, 0.0)],
        links=[((bad, 0.0), (1.0, 1.0)), Link((0.0, 0.0), (1.0, bad), width=bad), ((0.0, 0.0), (1.0, 1.0))],  # type: ignore[arg-type]
        guides=[((0.0, bad), (1.0, 1.0)), Link((bad, bad), (bad, bad))],
        phi=[bad, 0.5, bad], phi_bar_scale=bad, phi_units="m/s",
        field=lambda x, y: np.full((*np.shape(x), 2), bad),
        center=(bad, 0.0), extent=bad, text=["t = 0", str(bad)], arrow_scale=bad)
    assert _is_frame(renderer.draw(scene))
    everything_bad = Scene(bodies=[Body(bad, bad, heading=bad, size=bad, velocity=(bad, bad))],
                           links=[((bad, bad), (bad, bad))], guides=[((bad, bad), (bad, bad))], phi=[bad] * 3,
                           phi_bar_scale=bad, field=lambda x, y: np.full((*np.shape(x), 2), bad), center=(bad, bad),
                           extent=bad, arrow_scale=bad)
    assert _is_frame(renderer.draw(everything_bad))


def test_tiny_extent_and_far_camera_never_raise(renderer: PlanarRenderer) -> None:
    for center, extent in (((0.0, 0.0), 1e-300), ((0.0, 0.0), 5e-324), ((1e11, -1e11), 1e-6), ((0.0, 0.0), 1e12),
                           ((0.0, 0.0), 0.0), ((0.0, 0.0), -3.0)):
        f = renderer.draw(Scene(bodies=[Body(0.0, 0.0, heading=1.0), Body(1e11, 1.0)], links=[((0, 0), (1e11, 0))],
                                field=_current, center=center, extent=extent))
        assert _is_frame(f)


def test_malformed_scene_items_are_skipped_not_raised(renderer: PlanarRenderer) -> None:
    def failing(x, y):
        raise RuntimeError("no current here")

    for field in (failing, lambda x, y: np.zeros(3), lambda x, y: "water"):
        assert _is_frame(renderer.draw(Scene(bodies=[Body(0.0, 0.0)], field=field)))
    weird = Scene(bodies=[Body("a", None), Body(0.0, 0.0, color=(999, -1, 3)), "not a body"],  # type: ignore[arg-type, list-item]
                  links=[(1.0, 2.0, 3.0), None, ((0, 0), (1, "x"))], guides=[5], phi=["x", None, [1, 2]],  # type: ignore[list-item]
                  center=(1.0,), extent="wide", text=["nul \0 inside", "fine"])  # type: ignore[arg-type]
    assert _is_frame(renderer.draw(weird))
    assert _is_frame(renderer.draw(Scene(phi=np.array([0.1, -0.2]), text="one line")))  # type: ignore[arg-type]


# --------------------------------------------------------------------------- the phi panel


def test_every_phi_component_gets_a_bar(renderer: PlanarRenderer) -> None:
    def frame(phi: list[float]) -> np.ndarray:
        return renderer.draw(Scene(phi=phi, center=(0.0, 0.0), extent=10.0))

    empty = frame([])
    three = frame([0.5, 0.5, 0.5])
    changed = frame([0.5, 0.5, -0.5])
    # The panel sits in the top right; changing phi[2] changes pixels there and nowhere else.
    diff = np.any(three != changed, axis=-1)
    assert diff.any()
    rows, cols = np.nonzero(diff)
    assert cols.min() >= SCREEN_SIZE // 2 and rows.max() < SCREEN_SIZE // 2
    assert not _mask(empty, _PHI_BAR).any()
    # Three separate bars: down the bar column with the most bar pixels there are three runs.
    bars = _mask(three, _PHI_BAR)
    column = bars[:, int(np.argmax(bars.sum(axis=0)))]
    runs = int(np.sum(column[1:] & ~column[:-1]) + column[0])
    assert runs == 3
    # A bar's length follows its component (and a larger one is longer).
    short, long_ = _mask(frame([0.5, 0.5, 0.2]), _PHI_BAR).sum(), _mask(frame([0.5, 0.5, 0.9]), _PHI_BAR).sum()
    assert short < long_


@pytest.mark.parametrize("n", [1, 2, 7, 40, 1000])
def test_many_phi_components_still_render(renderer: PlanarRenderer, n: int) -> None:
    f = renderer.draw(Scene(phi=list(np.linspace(-0.9, 0.9, n)), phi_units="m/s"))
    assert _is_frame(f) and _mask(f, _PHI_BAR).any()
    saturated = renderer.draw(Scene(phi=[3.0] * n))  # beyond phi_bar_scale: clipped, in red
    assert _mask(saturated, _PHI_SATURATED).any() and not _mask(saturated, _PHI_BAR).any()


def test_phi_bar_scale_sets_the_full_bar(renderer: PlanarRenderer) -> None:
    small = _mask(renderer.draw(Scene(phi=[0.5], phi_bar_scale=10.0)), _PHI_BAR).sum()
    big = _mask(renderer.draw(Scene(phi=[0.5], phi_bar_scale=1.0)), _PHI_BAR).sum()
    assert 0 < small < big


def test_the_rewards_phi_scale_leaves_the_bars_alone() -> None:
    """An environment's ``phi_scale`` divides the raw reward only; the bars' length is the scene's
    ``phi_bar_scale``."""
    import gymnasium as gym

    import vnhc_gym  # noqa: F401

    frames = []
    for scale in (1.0, 100.0):
        env = gym.make("vnhc_gym/USVStream-v1", render_mode="rgb_array", phi_scale=scale)
        env.reset(seed=3)
        frames.append(env.render())
        env.close()
    assert _mask(frames[0], _PHI_BAR).any() and np.array_equal(frames[0], frames[1])


# --------------------------------------------------------------------------- the field


def test_quiver_only_with_a_field(renderer: PlanarRenderer) -> None:
    common = {"bodies": [Body(0.0, 0.0)], "center": (0.0, 0.0), "extent": 20.0}
    without = renderer.draw(Scene(**common))
    with_field = renderer.draw(Scene(**common, field=_current))
    assert not _mask(without, _CURRENT).any()
    assert _mask(with_field, _CURRENT).sum() > 100
    # A still field is water without arrows.
    still = renderer.draw(Scene(**common, field=lambda x, y: np.zeros((*np.shape(x), 2))))
    assert not _mask(still, _CURRENT).any() and not np.array_equal(still, without)


def test_quiver_is_fixed_to_the_world(renderer: PlanarRenderer) -> None:
    # Moving the camera by one quiver spacing (2 m at 20 m across) shows the same arrows.
    a = renderer.draw(Scene(field=_current, center=(0.0, 0.0), extent=20.0))
    b = renderer.draw(Scene(field=_current, center=(0.5, 0.0), extent=20.0))
    assert not np.array_equal(_mask(a, _CURRENT), _mask(b, _CURRENT))


# --------------------------------------------------------------------------- 3D helper


def test_axes_3d_projects_three_coloured_arrows(renderer: PlanarRenderer) -> None:
    links = axes_3d(np.eye(3), origin=(1.0, 2.0), length=2.0)
    assert len(links) == 3 and all(isinstance(lk, Link) and lk.arrow for lk in links)
    assert len({lk.color for lk in links}) == 3
    assert all(lk.start == (1.0, 2.0) for lk in links)
    z = next(lk for lk in links if lk.color == (52, 101, 164))  # the world z axis points up the screen
    assert z.end[0] == pytest.approx(1.0) and z.end[1] > 2.0 + 1.5
    for lk in links:  # projection never lengthens an axis
        assert math.hypot(lk.end[0] - 1.0, lk.end[1] - 2.0) <= 2.0 + 1e-12
    # A rotation changes the picture; a NaN matrix is drawn as nothing, without raising.
    c, s = math.cos(0.7), math.sin(0.7)
    turned = axes_3d(np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]))
    assert [lk.end for lk in turned] != [lk.end for lk in axes_3d(np.eye(3))]
    assert _is_frame(renderer.draw(Scene(links=axes_3d(np.full((3, 3), NAN)) + turned)))
    with pytest.raises(ValueError, match="3 x 3"):
        axes_3d(np.eye(2))


# --------------------------------------------------------------------------- modes and the display


def test_rgb_array_needs_no_video_driver(tmp_path: Path) -> None:
    # A fresh interpreter without SDL_VIDEODRIVER or DISPLAY: rgb_array never opens the display.
    code = ("import pygame\nfrom vnhc_gym.envs.rendering import PlanarRenderer, Scene, Body\n"
            "r = PlanarRenderer('rgb_array')\nf = r.draw(Scene(bodies=[Body(0.0, 0.0)], phi=[0.1]))\n"
            "assert f.shape == (500, 500, 3) and str(f.dtype) == 'uint8'\n"
            "assert not pygame.display.get_init()\nr.close()\nprint('ok')\n")
    env = {k: v for k, v in os.environ.items() if k not in ("SDL_VIDEODRIVER", "DISPLAY", "WAYLAND_DISPLAY")}
    env["PYTHONPATH"] = str(Path(__file__).resolve().parents[1])
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120,
                         cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().endswith("ok")


def test_headless_renders_of_every_environment_print_nothing(tmp_path: Path) -> None:
    """On a machine without a display, an rgb_array render of every registered environment prints
    nothing on stdout or stderr (no pygame greeting, no display probe); human mode says once that no
    window shows, in Gymnasium's warning, and prints nothing else."""
    from vnhc_gym.tasks import env_ids, shipped_tasks

    code = ("import warnings\nimport gymnasium as gym\nimport vnhc_gym\n"
            f"for env_id in {env_ids(shipped_only=True)!r}:\n"
            "    env = gym.make(env_id, render_mode='rgb_array')\n"
            "    env.reset(seed=0)\n"
            "    assert env.render().shape == (500, 500, 3)\n"
            "    env.close()\n"
            "with warnings.catch_warnings(record=True) as caught:\n"
            "    warnings.simplefilter('always')\n"
            "    env = gym.make(env_id, render_mode='human')\n"
            "    env.reset(seed=0)\n"
            "    env.close()\n"
            "import sys\nsys.stderr.write(''.join(str(w.message) for w in caught if 'display' in str(w.message)))\n")
    assert shipped_tasks()
    env = {k: v for k, v in os.environ.items()
           if k not in ("SDL_VIDEODRIVER", "SDL_AUDIODRIVER", "DISPLAY", "WAYLAND_DISPLAY", "XDG_RUNTIME_DIR",
                        "PYGAME_HIDE_SUPPORT_PROMPT")}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=600,
                         cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    assert out.stdout == ""
    assert "without a display" in out.stderr and "XDG" not in out.stderr
    assert out.stderr.count("\n") == 0, out.stderr  # the one warning, nothing else


def test_human_mode_shows_a_window_and_returns_none(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")
    r = PlanarRenderer("human", fps=1000, caption="test")
    assert r.draw(Scene(bodies=[Body(0.0, 0.0)])) is None
    r.close()
    r.close()  # closing twice is fine


def test_bad_render_mode_raises() -> None:
    with pytest.raises(ValueError, match="render_mode"):
        PlanarRenderer("ansi")


# --------------------------------------------------------------------------- the shipped tasks' renderers


def test_the_flock_is_drawn_from_its_state_and_phi() -> None:
    r = PlanarRenderer("rgb_array")

    def draw(state, phi):
        return r.draw(flock_scene(4, state, phi, 10.0))

    state = np.array([0.0, 5.0, 10.0, 3.0, 0.0, 2.0, -3.0, 1.0, 1.0, 1.0, 0.5, 1.0, 0.0, 0.5, 1.0, 0.2])
    phi = np.array([-5.6, 9.9, -12.6])
    f = draw(state, phi)
    assert _is_frame(f)
    moved = state.copy()
    moved[0] += 4.0
    assert not np.array_equal(f, draw(moved, phi))
    scene = flock_scene(4, state, phi, 10.0)
    assert len(scene.bodies) == 4 and len(scene.guides) == 3 and list(scene.phi) == list(phi)
    for bad in BAD:
        assert _is_frame(draw(np.full(16, bad), np.full(3, bad)))
        poked = state.copy()
        poked[[2, 9, 14]] = bad
        assert _is_frame(draw(poked, phi))
    r.close()


def test_the_boat_is_drawn_from_its_state_phi_and_current() -> None:
    r = PlanarRenderer("rgb_array")

    def draw(state, phi, current):
        return r.draw(hull_scene(state, phi, current))

    state = np.array([3.0, 1.0, 0.4, 1.5, 0.3, 0.0])
    f = draw(state, np.array([-0.48]), _current)
    assert _is_frame(f)
    assert _mask(f, _CURRENT).any()  # the current is the scene's field
    # The sled: no current, two phi components, both drawn.
    def no_current(x, y):
        return np.zeros((*np.shape(x), 2))

    still = draw(state, np.array([-0.1, -0.85]), no_current)
    assert _is_frame(still) and not _mask(still, _CURRENT).any()
    assert _mask(still, _PHI_BAR).sum() > _mask(draw(state, np.array([-0.1]), no_current), _PHI_BAR).sum()
    for bad in BAD:
        assert _is_frame(draw(np.full(6, bad), np.array([bad]), _current))
        assert _is_frame(draw(np.array([0.0, 0.0, bad, bad, 1.0, 0.0]), np.array([0.1]), _current))
        assert _is_frame(draw(state, np.array([0.1]), lambda x, y, v=bad: np.full((*np.shape(x), 2), v)))
    r.close()
