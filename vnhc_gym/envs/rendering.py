"""Pygame renderers: a generic planar scene, and the flock and the boat (or sled) drawn with it.

A task describes each frame declaratively as a [`Scene`][vnhc_gym.envs.rendering.Scene] (bodies, links, guide lines, the
components of ``phi``, an optional background vector field) and
[`PlanarRenderer`][vnhc_gym.envs.rendering.PlanarRenderer] draws it.  `flock_scene` and
`hull_scene` turn the flock's and the boat's (or sled's) state arrays into a
[`Scene`][vnhc_gym.envs.rendering.Scene].  `axes_3d` projects a rotation matrix's body axes onto the
screen so that a spatial task can be drawn with the same renderer.

Everything follows Gymnasium's classic-control pattern: the frame is drawn on an off-screen
``pygame.Surface``.  ``render_mode="rgb_array"`` returns it as a ``uint8 (H, W, 3)`` array and
never touches ``pygame.display`` (so it works headless, without ``SDL_VIDEODRIVER`` tricks);
``render_mode="human"`` opens a window, shows the frame, ticks a clock at ``fps`` and returns
``None``.  The renderers only read what they are given and skip anything non-finite or huge
(nothing is drawn for it), so that rendering can never crash an episode.

Examples
--------
>>> from vnhc_gym.envs.rendering import Body, Link, PlanarRenderer, Scene
>>> r = PlanarRenderer("rgb_array")
>>> frame = r.draw(Scene(bodies=[Body(0.0, 0.0, heading=0.3, size=2.0, velocity=(1.0, 0.5))],
...                      links=[Link((0.0, 0.0), (0.0, 1.5))], phi=[0.1, -0.4], phi_units="m/s"))
>>> frame.shape, frame.dtype
((500, 500, 3), dtype('uint8'))
>>> r.close()
"""

from __future__ import annotations

import math
import os
import sys
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ["SCREEN_SIZE", "Body", "Link", "PlanarRenderer", "Scene", "axes_3d", "flock_scene", "hull_scene"]

SCREEN_SIZE = 500  #: frames are SCREEN_SIZE x SCREEN_SIZE pixels
_PIX_LIMIT = 10.0 * SCREEN_SIZE  # pixel coordinates are clipped to +-this (pygame needs C ints)
_WORLD_LIMIT = 1e12  # metres; beyond this a coordinate is treated as unusable (float spacing ~ 1e-4 m)
_MIN_EXTENT = 5.0  # metres across the frame when the camera fits the scene by itself

Color = tuple[int, int, int]
Point = tuple[float, float]

_BG = (255, 255, 255)
_GRID = (228, 228, 228)
_TEXT = (20, 20, 20)
_FOLLOWER = (52, 101, 164)
_LEADER = (204, 0, 0)
_GUIDE = (200, 200, 200)
_LINK = (60, 60, 60)
_WATER = (222, 236, 250)
_CURRENT = (90, 140, 200)
_HULL = (90, 90, 90)
_VEL = (204, 0, 0)
_REL = (0, 150, 60)
_PANEL = (250, 250, 250)
_PANEL_EDGE = (170, 170, 170)
_PHI_BAR = (52, 101, 164)
_PHI_SATURATED = (204, 0, 0)  # the bar is clipped: |phi| exceeds phi_bar_scale
_AXIS_COLORS: tuple[Color, Color, Color] = ((204, 0, 0), (0, 150, 60), (52, 101, 164))  # body x, y, z


# --------------------------------------------------------------------------- scene description


@dataclass(frozen=True)
class Body:
    """A rigid body or a particle in the plane (metres, radians).

    Parameters
    ----------
    x, y : float
        Position (m).
    heading : float or None
        ``None`` draws a disc; otherwise a pointed hull whose bow points along
        ``(cos heading, sin heading)``.
    size : float
        Length of the hull, or radius of the disc (m).  Tiny bodies are drawn at a few pixels so
        they stay visible.
    velocity : (float, float) or None
        Drawn as an arrow from the body, in its colour (m/s; see `Scene.arrow_scale`).
    color : (int, int, int)
        RGB fill colour.
    label : str or None
        Written next to the body.
    """

    x: float
    y: float
    heading: float | None = None
    size: float = 0.5
    velocity: tuple[float, float] | None = None
    color: Color = _FOLLOWER
    label: str | None = None


@dataclass(frozen=True)
class Link:
    """A straight segment between two points (m): a rod, a pole, a track, a body axis or an arrow.

    Parameters
    ----------
    start, end : (float, float)
        End points (m).
    color : (int, int, int)
        RGB colour.
    width : int
        Line width in pixels (a pixel width keeps thin and thick lines readable at any zoom).
    arrow : bool
        Draw an arrow head at ``end``.
    """

    start: Point
    end: Point
    color: Color = _LINK
    width: int = 4
    arrow: bool = False


#: What `Scene.links` and `Scene.guides` accept: a [`Link`][vnhc_gym.envs.rendering.Link] or a bare ``(start, end)``.
LinkLike = Link | tuple[Point, Point]


@dataclass(frozen=True)
class Scene:
    """What one frame shows.

    Parameters
    ----------
    bodies : sequence of Body
        Discs and hulls, drawn over the guides and under the links.
    links : sequence of Link or (start, end)
        Rods, poles, tracks, arrows; a bare ``(start, end)`` pair is a dark 4-pixel line.  Drawn
        last, so that a pole or an axis shows over the body it is attached to.
    guides : sequence of Link or (start, end)
        Thin lines under everything (desired directions, rails); a bare pair is a 1-pixel grey line.
    phi : sequence of float
        Every component of the constraint ``phi``, shown as labelled bars with their values in a
        panel at the top right.  A bar spans half the panel's bar area when ``|phi| = phi_bar_scale``
        and is drawn red (clipped) beyond it; non-finite components get no bar.
    phi_bar_scale : float
        ``|phi|`` of a full-length bar (a non-positive or non-finite value means 1).  A length on
        the picture only: the environments' ``phi_scale`` is the raw reward's divisor and does not
        change the bars.
    phi_units : str
        Units written in the panel's title.
    field : callable or None
        ``field(x, y) -> (..., 2)``: a background vector field (e.g. a water current, m/s)
        evaluated on a world-fixed grid and drawn as a quiver over a water-coloured background.
        Arrows are scaled by the largest value in view (at least 1).  A field that raises or
        returns the wrong shape is not drawn.
    center : (float, float) or None
        Camera centre (m).  Default: the mean of the bodies (of the link end points if there are
        no bodies; the origin if there is nothing).
    extent : float or None
        Metres shown across the frame.  Default: fit the bodies and links with a margin, at least
        5 m.
    text : sequence of str
        Extra lines (time, reward, ...) written at the top left, above the grid spacing.
    arrow_scale : float or None
        Seconds: a body's velocity arrow is ``arrow_scale * velocity`` metres long (capped at 0.45
        of the frame).  ``None`` scales the longest velocity arrow to 12 % of the frame.
    """

    bodies: Sequence[Body] = ()
    links: Sequence[LinkLike] = ()
    guides: Sequence[LinkLike] = ()
    phi: Sequence[float] = ()
    phi_bar_scale: float = 1.0
    phi_units: str = ""
    field: Callable[[NDArray[np.float64], NDArray[np.float64]], NDArray[np.float64]] | None = None
    center: Point | None = None
    extent: float | None = None
    text: Sequence[str] = ()
    arrow_scale: float | None = None


# --------------------------------------------------------------------------- helpers


def _import_pygame() -> Any:
    # pygame prints a greeting on stdout when first imported; a render prints nothing.
    os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")
    try:
        import pygame
    except ImportError as e:  # pragma: no cover - depends on the installation
        from gymnasium.error import DependencyNotInstalled

        raise DependencyNotInstalled('pygame is not installed: pip install "vnhc-gym[render]"') from e
    return pygame


def _finite(*values: float) -> bool:
    return all(math.isfinite(v) for v in values)


def _num(v: Any) -> float:
    """``float(v)``, or NaN for anything that is not a real number (a Scene is never trusted)."""
    try:
        out = float(v)
    except (TypeError, ValueError, OverflowError):
        return math.nan
    return out


def _usable(*values: float) -> bool:
    """Finite and small enough that world-to-pixel arithmetic stays exact enough to draw."""
    return all(math.isfinite(v) and abs(v) <= _WORLD_LIMIT for v in values)


def _point(p: Any) -> Point | None:
    """A usable ``(x, y)`` from any pair-like value, or None."""
    try:
        x, y = p
    except (TypeError, ValueError):
        return None
    x, y = _num(x), _num(y)
    return (x, y) if _usable(x, y) else None


def _as_link(item: Any, default_color: Color, default_width: int) -> Link | None:
    """A [`Link`][vnhc_gym.envs.rendering.Link] with usable end points, or None (bare pairs take the given defaults)."""
    if isinstance(item, Link):
        a, b, color, width, arrow = item.start, item.end, item.color, item.width, item.arrow
    else:
        try:
            a, b = item
        except (TypeError, ValueError):
            return None
        color, width, arrow = default_color, default_width, False
    pa, pb = _point(a), _point(b)
    if pa is None or pb is None:
        return None
    w = _num(width)
    return Link(pa, pb, color, int(min(max(w, 1.0), 50.0)) if math.isfinite(w) else default_width, bool(arrow))


def _clip_px(p: Point) -> Point:
    return (min(max(p[0], -_PIX_LIMIT), _PIX_LIMIT), min(max(p[1], -_PIX_LIMIT), _PIX_LIMIT))


def _nice_step(raw: float) -> float:
    """The smallest of 1, 2, 5 times a power of ten that is >= ``raw``."""
    if not (math.isfinite(raw) and raw > 0):
        return 1.0
    exp = math.floor(math.log10(raw))
    for mult in (1.0, 2.0, 5.0, 10.0):
        step = mult * 10.0**exp
        if step >= raw:
            return step
    return 10.0 ** (exp + 1)  # pragma: no cover - unreachable


def _fmt(v: float) -> str:
    return f"{v: .3e}" if math.isfinite(v) else str(v)


class _Canvas:
    """Off-screen surface, optional window, font and the world-to-pixel map (y up)."""

    def __init__(self, render_mode: str, fps: float, caption: str) -> None:
        if render_mode not in ("human", "rgb_array"):
            raise ValueError(f"render_mode must be 'human' or 'rgb_array', got {render_mode!r}")
        self.pg = _import_pygame()
        self.render_mode = render_mode
        self.fps = fps
        self.size = SCREEN_SIZE
        self.surf = self.pg.Surface((self.size, self.size))
        self.window: Any = None
        self.clock: Any = None
        if render_mode == "human":
            if sys.platform.startswith("linux") and not any(
                    os.environ.get(k) for k in ("SDL_VIDEODRIVER", "WAYLAND_DISPLAY", "DISPLAY")):
                # No display: SDL would probe Wayland, whose library prints "XDG_RUNTIME_DIR is
                # invalid" on stderr, then draw into no window.  Say so once, and skip the probe.
                from gymnasium import logger

                logger.warn("render_mode='human' on a machine without a display (no DISPLAY or WAYLAND_DISPLAY): "
                            "no window is shown; use render_mode='rgb_array' for frames")
                os.environ["SDL_VIDEODRIVER"] = "dummy"
            self.pg.display.init()
            self.pg.display.set_caption(caption)
            self.window = self.pg.display.set_mode((self.size, self.size))
            self.clock = self.pg.time.Clock()
        self.font: Any = None
        try:  # pygame may be built without SDL_ttf
            self.pg.font.init()
            self.font = self.pg.font.Font(None, 20)
        except Exception:  # noqa: BLE001 - any failure just means no text
            self.font = None
        self.cx = 0.0
        self.cy = 0.0
        self.scale = 1.0  # pixels per metre

    # ----------------------------------------------------------------- coordinates
    def view(self, cx: float, cy: float, scale: float) -> None:
        self.cx, self.cy, self.scale = cx, cy, scale

    def px(self, x: float, y: float) -> Point:
        h = self.size / 2.0
        return _clip_px((h + (x - self.cx) * self.scale, h - (y - self.cy) * self.scale))

    # ----------------------------------------------------------------- primitives
    def grid(self) -> float | None:
        """World grid lines at a 'nice' spacing of about 50 pixels (shows the camera motion).

        Returns the spacing in metres, or None when no grid could be drawn.
        """
        half = self.size / (2.0 * self.scale)
        step = _nice_step(50.0 / self.scale)
        if not _finite(half, step, self.cx, self.cy) or half / step > 100 \
                or max(abs(self.cx), abs(self.cy)) / step > 1e12:  # lines would not advance in float
            return None
        for centre, vertical in ((self.cx, True), (self.cy, False)):
            k = math.ceil((centre - half) / step)
            while k * step <= centre + half:
                v = k * step
                if vertical:
                    a, b = self.px(v, self.cy - half), self.px(v, self.cy + half)
                else:
                    a, b = self.px(self.cx - half, v), self.px(self.cx + half, v)
                self.pg.draw.line(self.surf, _GRID, a, b, 1)
                k += 1
        return step

    def arrow(self, start: Point, end: Point, color: Color, width: int = 2, head: float = 8.0) -> None:
        """Arrow between two pixel points (nothing if degenerate or non-finite)."""
        if not _finite(*start, *end):
            return
        dx, dy = end[0] - start[0], end[1] - start[1]
        length = math.hypot(dx, dy)
        if length < 1.0:
            return
        self.pg.draw.line(self.surf, color, start, end, width)
        ux, uy = dx / length, dy / length
        hl = min(head, 0.5 * length)
        hw = 0.5 * hl
        base = (end[0] - hl * ux, end[1] - hl * uy)
        self.pg.draw.polygon(self.surf, color, [end, (base[0] - hw * uy, base[1] + hw * ux),
                                                (base[0] + hw * uy, base[1] - hw * ux)])

    def text(self, lines: Sequence[str], pos: Point = (8.0, 6.0), color: Color = _TEXT) -> None:
        if self.font is None:
            return
        y = pos[1]
        for line in lines:
            try:  # a string pygame cannot render (e.g. with a NUL) is skipped, not fatal
                img = self.font.render(str(line), True, color)
            except Exception:  # noqa: BLE001
                continue
            self.surf.blit(img, (pos[0], y))
            y += img.get_height() + 2

    # ----------------------------------------------------------------- output
    def show(self) -> NDArray[np.uint8] | None:
        if self.render_mode == "human":
            assert self.window is not None and self.clock is not None
            self.pg.event.pump()
            self.window.blit(self.surf, (0, 0))
            self.pg.display.flip()
            self.clock.tick(self.fps)
            return None
        frame = self.pg.surfarray.array3d(self.surf)  # (W, H, 3), a copy
        return np.ascontiguousarray(np.transpose(frame, (1, 0, 2)), dtype=np.uint8)

    def close(self) -> None:
        if self.window is not None:
            self.pg.display.quit()
            self.window = None
        self.clock = None
        self.font = None


# --------------------------------------------------------------------------- the generic renderer


class PlanarRenderer:
    """Draws a [`Scene`][vnhc_gym.envs.rendering.Scene]: the world seen from above, y up, on a grid
    that moves with the camera.

    Layers, bottom to top: background (water-coloured when the scene has a ``field``), grid,
    field quiver, guides, bodies (velocity arrow, then the disc or hull), links, body labels,
    the ``phi`` panel (top right) and the text lines with the grid spacing (top left).

    Parameters
    ----------
    render_mode : {"rgb_array", "human"}
        ``rgb_array``: [`draw`][vnhc_gym.envs.rendering.PlanarRenderer.draw] returns the frame;
        ``human``: it shows the frame in a window and waits for the next tick of an ``fps`` clock.
    fps : float
        Frames per second in ``human`` mode.
    caption : str
        Window title in ``human`` mode.
    """

    def __init__(self, render_mode: str, fps: float = 20, caption: str = "vnhc_gym") -> None:
        self._canvas = _Canvas(render_mode, fps, caption)
        self.render_mode = render_mode

    # ----------------------------------------------------------------- public
    def draw(self, scene: Scene) -> NDArray[np.uint8] | None:
        """Draw one frame.

        Parameters
        ----------
        scene : Scene
            What to show.  Items with non-finite or huge (> 1e12 m) numbers are skipped.

        Returns
        -------
        ndarray of uint8, shape (SCREEN_SIZE, SCREEN_SIZE, 3), or None
            The frame in ``rgb_array`` mode; None in ``human`` mode.
        """
        c = self._canvas
        bodies = [b for b in self._iter(scene, "bodies") if isinstance(b, Body) and _usable(_num(b.x), _num(b.y))]
        links = [lk for lk in (_as_link(i, _LINK, 4) for i in self._iter(scene, "links")) if lk is not None]
        guides = [lk for lk in (_as_link(i, _GUIDE, 1) for i in self._iter(scene, "guides")) if lk is not None]
        field = getattr(scene, "field", None)
        c.surf.fill(_WATER if field is not None else _BG)
        self._camera(scene, bodies, links)
        step = c.grid()
        # Each layer is guarded on its own: a bad item costs that item, never the frame.
        for layer in (lambda: self._quiver(field) if field is not None else None,
                      lambda: self._links(guides),
                      lambda: self._bodies(bodies, getattr(scene, "arrow_scale", None)),
                      lambda: self._links(links),
                      lambda: self._labels(bodies),
                      lambda: self._phi_panel(scene)):
            try:
                layer()
            except Exception:  # noqa: BLE001 - rendering must never end an episode
                pass
        lines = [str(t) for t in self._iter(scene, "text")]
        if step is not None:
            lines.append(f"grid {step:g} m")
        c.text(lines)
        return c.show()

    def close(self) -> None:
        """Close the window (if any); closing twice is fine."""
        self._canvas.close()

    # ----------------------------------------------------------------- camera
    @staticmethod
    def _iter(scene: Scene, name: str) -> list[Any]:
        value = getattr(scene, name, ())
        if isinstance(value, str):  # one line of text, not its characters
            return [value]
        if value is None:
            return []
        try:
            return list(value)
        except (TypeError, ValueError):
            return []

    def _camera(self, scene: Scene, bodies: list[Body], links: list[Link]) -> None:
        c = self._canvas
        pts = [(_num(b.x), _num(b.y)) for b in bodies]
        ends = [p for lk in links for p in (lk.start, lk.end)]
        centre = _point(getattr(scene, "center", None))
        if centre is None:
            base = pts or ends
            centre = (math.fsum(p[0] for p in base) / len(base), math.fsum(p[1] for p in base) / len(base)) \
                if base else (0.0, 0.0)
        extent = _num(getattr(scene, "extent", None))
        if not (_usable(extent) and extent > 1e-9):  # below a nanometre the scale would overflow
            reach = 0.0
            for b in bodies:
                size = _num(b.size)
                r = max(abs(_num(b.x) - centre[0]), abs(_num(b.y) - centre[1]))
                reach = max(reach, r + (size if _usable(size) and size > 0 else 0.0))
            for p in ends:
                reach = max(reach, abs(p[0] - centre[0]), abs(p[1] - centre[1]))
            extent = max(2.0 * 1.2 * reach, _MIN_EXTENT)
            if not _usable(extent):
                extent = _MIN_EXTENT
        c.view(centre[0], centre[1], c.size / extent)

    # ----------------------------------------------------------------- layers
    def _quiver(self, field: Callable[..., Any]) -> None:
        """The field on a world-fixed grid (about ten arrows across), so it slides past as the camera moves."""
        c = self._canvas
        extent = c.size / c.scale
        h = _nice_step(extent / 10.0)
        half = extent / 2.0 + h
        if max(abs(c.cx), abs(c.cy)) / h > 1e12:  # grid points would not be distinct in float
            return
        xs = h * np.arange(math.floor((c.cx - half) / h), math.ceil((c.cx + half) / h) + 1)
        ys = h * np.arange(math.floor((c.cy - half) / h), math.ceil((c.cy + half) / h) + 1)
        gx, gy = np.meshgrid(xs, ys)
        try:
            with np.errstate(all="ignore"):
                vel = np.asarray(field(gx, gy), dtype=np.float64)
        except Exception:  # noqa: BLE001 - a user's field that fails is not drawn
            return
        if vel.shape != (*gx.shape, 2):
            return
        with np.errstate(all="ignore"):
            mag = np.hypot(vel[..., 0], vel[..., 1])
        good = np.isfinite(mag)
        if not good.any():
            return
        k = 0.8 * h / max(float(mag[good].max()), 1.0)
        for j, i in zip(*np.nonzero(good), strict=True):
            x0, y0 = float(gx[j, i]), float(gy[j, i])
            u, v = float(vel[j, i, 0]), float(vel[j, i, 1])
            a = c.px(x0 - 0.5 * k * u, y0 - 0.5 * k * v)
            b = c.px(x0 + 0.5 * k * u, y0 + 0.5 * k * v)
            c.arrow(a, b, _CURRENT, width=1, head=6.0)

    def _links(self, links: Iterable[Link]) -> None:
        c = self._canvas
        for lk in links:
            a, b = c.px(*lk.start), c.px(*lk.end)
            if lk.arrow:
                c.arrow(a, b, lk.color, width=lk.width, head=max(8.0, 2.5 * lk.width))
            else:
                c.pg.draw.line(c.surf, lk.color, a, b, lk.width)

    def _bodies(self, bodies: list[Body], arrow_scale: Any) -> None:
        c = self._canvas
        extent = c.size / c.scale
        vels: list[tuple[float, float] | None] = []
        for b in bodies:
            v = _point(b.velocity) if b.velocity is not None else None
            vels.append(v if v is not None and (v[0] != 0.0 or v[1] != 0.0) else None)
        scale = _num(arrow_scale)
        if not (_usable(scale) and scale > 0):
            vmax = max((math.hypot(*v) for v in vels if v is not None), default=0.0)
            scale = 0.12 * extent / vmax if vmax > 0 else 0.0
        for b, v in zip(bodies, vels, strict=True):
            try:
                self._body(b, v, scale, extent)
            except Exception:  # noqa: BLE001 - e.g. a colour pygame refuses: skip that body
                continue

    def _body(self, b: Body, v: Point | None, arrow_scale: float, extent: float) -> None:
        c = self._canvas
        pg = c.pg
        x, y = _num(b.x), _num(b.y)
        origin = c.px(x, y)
        if v is not None and arrow_scale > 0:
            speed = math.hypot(*v)
            k = min(arrow_scale, 0.45 * extent / speed)
            c.arrow(origin, c.px(x + k * v[0], y + k * v[1]), b.color, width=2)
        size = _num(b.size)
        size_px = size * c.scale if _usable(size) and size > 0 else 0.0
        heading = _num(b.heading) if b.heading is not None else None
        if heading is None or not math.isfinite(heading):
            # A disc (also the fallback for a non-finite heading: the position is still known).
            r = int(round(min(max(size_px, 4.0), _PIX_LIMIT)))
            pg.draw.circle(c.surf, b.color, (int(round(origin[0])), int(round(origin[1]))), r)
            return
        # Hull: bow at +0.58 length, stern corners at -0.42 length, half a length wide,
        # at least 12 pixels long so a small boat still shows its heading.
        length = max(size_px, 12.0) / c.scale
        ct, st = math.cos(heading), math.sin(heading)
        pts = [(1.4, 0.0), (-1.0, 0.5), (-0.7, 0.0), (-1.0, -0.5)]
        s = length / 2.4
        hull = [c.px(x + s * (a * ct - d * st), y + s * (a * st + d * ct)) for a, d in pts]
        pg.draw.polygon(c.surf, b.color, hull)
        pg.draw.polygon(c.surf, (0, 0, 0), hull, 1)

    def _labels(self, bodies: list[Body]) -> None:
        c = self._canvas
        for b in bodies:
            if b.label:
                p = c.px(_num(b.x), _num(b.y))
                size = _num(b.size)
                off = 6.0 + (min(size * c.scale, 40.0) if _usable(size) and size > 0 else 0.0)
                c.text([str(b.label)], (p[0] + off, p[1] - off - 12.0))

    def _phi_panel(self, scene: Scene) -> None:
        """One labelled bar per ``phi`` component, centred on zero, with its value.

        Up to 16 pixels a row; rows shrink to 4 pixels (bars only, no text below 12) as the
        components grow in number, and beyond what fits the last row counts the rest and gives
        their largest ``|phi|``.
        """
        c = self._canvas
        pg = c.pg
        try:
            phi = [_num(v) for v in np.asarray(scene.phi, dtype=object).ravel()]
        except Exception:  # noqa: BLE001
            return
        if not phi:
            return
        scale = _num(getattr(scene, "phi_bar_scale", 1.0))
        if not (math.isfinite(scale) and scale > 0):
            scale = 1.0
        width, x0, y0 = 210, c.size - 218, 8
        title_h = 18 if c.font is not None else 0
        avail = 0.6 * c.size - title_h
        row = int(min(16, max(4, avail // len(phi))))
        n_rows = len(phi) if len(phi) * row <= avail else int(avail // row)
        shown, hidden = (phi, []) if n_rows >= len(phi) else (phi[: n_rows - 1], phi[n_rows - 1:])
        height = title_h + row * len(shown) + (18 if hidden and c.font is not None else 0) + 6
        pg.draw.rect(c.surf, _PANEL, (x0, y0, width, height))
        pg.draw.rect(c.surf, _PANEL_EDGE, (x0, y0, width, height), 1)
        units = str(getattr(scene, "phi_units", "") or "")
        c.text([f"phi{' (' + units + ')' if units else ''}, bar = {scale:g}"], (x0 + 5, y0 + 3))
        labels = row >= 12 and c.font is not None
        bar_x, bar_half = x0 + (50 if labels else 8), 40 if labels else (width - 16) // 2
        mid = bar_x + bar_half
        top = y0 + title_h + 3
        pg.draw.line(c.surf, _PANEL_EDGE, (mid, top), (mid, top + row * len(shown) - 1), 1)
        for k, v in enumerate(shown):
            ry = top + k * row
            if labels:
                c.text([f"phi_{k + 1}"], (x0 + 6, ry))
                c.text([_fmt(v)], (mid + bar_half + 6, ry))
            if not math.isfinite(v):
                continue
            frac = min(max(v / scale, -1.0), 1.0)
            length = int(round(frac * bar_half))
            color = _PHI_SATURATED if abs(v) > scale else _PHI_BAR
            bar_h = max(row - 4, 2) if row >= 8 else max(row - 1, 1)
            left = mid if length >= 0 else mid + length
            if length != 0:
                pg.draw.rect(c.surf, color, (left, ry + (row - bar_h) // 2, abs(length), bar_h))
        if hidden:
            fin = [abs(v) for v in hidden if math.isfinite(v)]
            worst = _fmt(max(fin)) if fin else "nan"
            c.text([f"+{len(hidden)} more, max |phi| {worst}"], (x0 + 6, top + len(shown) * row + 2))


# --------------------------------------------------------------------------- 3D helper

#: Fixed oblique view of `axes_3d`: azimuth and elevation of the viewer (rad); the world
#: z axis points up the screen, x towards the viewer's lower left, y to the right.
VIEW_AZIMUTH = math.radians(35.0)
VIEW_ELEVATION = math.radians(25.0)


def axes_3d(R: NDArray[np.float64], origin: Point = (0.0, 0.0), length: float = 1.0, *,
            width: int = 3) -> list[Link]:
    """The three body axes of a rotation matrix, projected onto the screen plane as arrows.

    An orthographic view from a fixed direction (`VIEW_AZIMUTH`, `VIEW_ELEVATION`)
    keeps the picture of a spinning body readable without a 3D engine.  The axes come back
    sorted far to near, so drawing them in order puts the nearer ones on top.

    Parameters
    ----------
    R : array_like, shape (3, 3)
        Rotation matrix whose columns are the body axes in world coordinates.
    origin : (float, float)
        Where the body's centre is drawn in the scene (m).
    length : float
        Length of each axis before projection (m).
    width : int
        Line width (pixels).

    Returns
    -------
    list of Link
        Three arrows, body x red, y green, z blue, to pass as (part of) `Scene.links`.
        Non-finite entries give non-finite end points, which the renderer skips.

    Raises
    ------
    ValueError
        If ``R`` is not 3 x 3.
    """
    m = np.asarray(R, dtype=np.float64)
    if m.shape != (3, 3):
        raise ValueError(f"R must be a 3 x 3 rotation matrix, got shape {m.shape}")
    az, el = VIEW_AZIMUTH, VIEW_ELEVATION
    right = np.array([-math.sin(az), math.cos(az), 0.0])
    up = np.array([-math.sin(el) * math.cos(az), -math.sin(el) * math.sin(az), math.cos(el)])
    toward = np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
    ox, oy = float(origin[0]), float(origin[1])
    axes = []
    with np.errstate(all="ignore"):
        for k in range(3):
            a = length * m[:, k]
            end = (ox + float(a @ right), oy + float(a @ up))
            axes.append((float(a @ toward), Link((ox, oy), end, _AXIS_COLORS[k], width, arrow=True)))
    # NaN depths sort arbitrarily; those links are skipped at drawing anyway.
    axes.sort(key=lambda t: t[0] if math.isfinite(t[0]) else -math.inf)
    return [lk for _, lk in axes]


# --------------------------------------------------------------------------- the shipped tasks


def flock_scene(n_agents: int, state: NDArray[np.float64], phi: NDArray[np.float64],
                phi_bar_scale: float = 10.0) -> Scene:
    """Particles in their vertical plane: ``state`` is ``(x, z, xd, zd)``, each ``(n_agents,)``, the
    leader (red) last; a grey guide through each follower along the leader's direction of motion;
    the camera on the group's centroid, at least 30 m across; ``phi`` as bars, full length at
    ``phi_bar_scale``."""
    n = n_agents
    x, z, vx, vz = np.asarray(state, dtype=np.float64).reshape(4, n)
    ok = np.isfinite(x) & np.isfinite(z) & (np.abs(x) <= _WORLD_LIMIT) & (np.abs(z) <= _WORLD_LIMIT)
    centre: Point | None = None
    extent: float | None = None
    if ok.any():
        with np.errstate(all="ignore"):
            cx, cz = float(np.mean(x[ok])), float(np.mean(z[ok]))
            extent = 3.0 * float(max(np.max(np.abs(x[ok] - cx)), np.max(np.abs(z[ok] - cz)), 10.0))
        centre = (cx, cz)
    px_per_m = SCREEN_SIZE / extent if extent is not None and _usable(extent) else 1.0
    lead = n - 1
    lvx, lvz = float(vx[lead]), float(vz[lead])
    lsp = math.hypot(lvx, lvz) if _finite(lvx, lvz) else math.nan
    guides = []
    if _finite(lsp) and lsp > 0:
        ex, ez = 45.0 / px_per_m * lvx / lsp, 45.0 / px_per_m * lvz / lsp  # 45 px either side
        guides = [((float(x[i]) - ex, float(z[i]) - ez), (float(x[i]) + ex, float(z[i]) + ez))
                  for i in range(n - 1) if ok[i]]
    bodies = [Body(float(x[i]), float(z[i]), size=(7.0 if i == lead else 6.0) / px_per_m,
                   velocity=(float(vx[i]), float(vz[i])), color=_LEADER if i == lead else _FOLLOWER)
              for i in range(n) if ok[i]]
    return Scene(bodies=bodies, guides=guides, phi=[float(v) for v in np.asarray(phi, np.float64).ravel()],
                 phi_bar_scale=phi_bar_scale, phi_units="m^2/s^2", center=centre, extent=extent)


def _arrow_tip(x: float, y: float, vx: float, vy: float, arrow_scale: float, view_width: float) -> Point:
    """Tip of a velocity arrow from ``(x, y)``: ``arrow_scale`` m per m/s, at most 0.45 view widths."""
    speed = math.hypot(vx, vy)
    k = arrow_scale if speed * arrow_scale <= 0.45 * view_width else 0.45 * view_width / speed
    return x + k * vx, y + k * vy


def hull_scene(state: NDArray[np.float64], phi: NDArray[np.float64], current: Callable[[Any, Any], Any] | None = None,
               *, phi_bar_scale: float = 1.0, phi_units: str = "m/s", view_width: float = 20.0,
               arrow_scale: float = 2.0, size: float = 2.4) -> Scene:
    """A planar rigid body seen from above, ``state`` starting ``(x, y, theta, xd, yd, ...)``: its
    hull along ``theta`` and its velocity (red), in a ``view_width`` view centred on it; with a
    ``current(x, y) -> (..., 2)``, the water as a quiver and the velocity through the water (green)."""
    x, y, th, xd, yd, _ = (float(v) for v in np.asarray(state, dtype=np.float64).ravel()[:6])
    centred = _usable(x, y)
    bodies, links = [], []
    if centred:
        bodies.append(Body(x, y, heading=th, size=size, color=_HULL))  # a NaN heading leaves a disc
        if _finite(xd, yd):
            links.append(Link((x, y), _arrow_tip(x, y, xd, yd, arrow_scale, view_width), _VEL, 3, arrow=True))
            water = np.full(2, np.nan)
            if current is not None:
                try:
                    with np.errstate(all="ignore"):
                        water = np.asarray(current(np.array([x]), np.array([y])), dtype=np.float64).reshape(-1)[:2]
                except Exception:  # noqa: BLE001 - no relative-velocity arrow then
                    water = np.full(2, np.nan)
            if water.shape == (2,) and np.all(np.isfinite(water)):
                rx, ry = xd - float(water[0]), yd - float(water[1])
                links.append(Link((x, y), _arrow_tip(x, y, rx, ry, arrow_scale, view_width), _REL, 3, arrow=True))
    text = [f"x = {x:.2f} m, y = {y:.2f} m" if centred else "position not finite",
            "red: velocity" + (", green: relative to water" if current is not None else "")]
    return Scene(bodies=bodies, links=links, phi=[float(v) for v in np.asarray(phi, np.float64).ravel()],
                 phi_bar_scale=phi_bar_scale, phi_units=phi_units, field=current,
                 center=(x, y) if centred else (0.0, 0.0), extent=view_width, text=text)
