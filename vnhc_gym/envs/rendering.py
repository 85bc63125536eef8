"""Pygame renderers: the flock in its plane, and a boat (or a sled) seen from above.

Both follow Gymnasium's classic-control pattern: everything is drawn on an off-screen
``pygame.Surface``.  ``render_mode="rgb_array"`` returns it as a ``uint8 (H, W, 3)`` array and
never touches ``pygame.display`` (so it works headless, without ``SDL_VIDEODRIVER`` tricks);
``render_mode="human"`` opens a window, shows the frame, ticks a clock at ``fps`` and returns
``None``.  The renderers only read the arrays they are given and cope with non-finite or huge
numbers (nothing is drawn for them) so that rendering can never crash an episode.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ["FlockingRenderer", "USVRenderer", "SCREEN_SIZE"]

SCREEN_SIZE = 500  #: frames are SCREEN_SIZE x SCREEN_SIZE pixels
_PIX_LIMIT = 10.0 * SCREEN_SIZE  # pixel coordinates are clipped to +-this (pygame needs C ints)

_BG = (255, 255, 255)
_GRID = (228, 228, 228)
_TEXT = (20, 20, 20)
_FOLLOWER = (52, 101, 164)
_LEADER = (204, 0, 0)
_GUIDE = (200, 200, 200)
_WATER = (222, 236, 250)
_CURRENT = (90, 140, 200)
_HULL = (90, 90, 90)
_VEL = (204, 0, 0)
_REL = (0, 150, 60)

Point = tuple[float, float]


def _import_pygame() -> Any:
    try:
        import pygame
    except ImportError as e:  # pragma: no cover - depends on the installation
        from gymnasium.error import DependencyNotInstalled

        raise DependencyNotInstalled('pygame is not installed: pip install "vnhc-gym[render]"') from e
    return pygame


def _finite(*values: float) -> bool:
    return all(math.isfinite(v) for v in values)


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
    def grid(self) -> None:
        """World grid lines at a 'nice' spacing of about 50 pixels (shows the camera motion)."""
        half = self.size / (2.0 * self.scale)
        step = _nice_step(50.0 / self.scale)
        if not _finite(half, step, self.cx, self.cy) or half / step > 100 \
                or max(abs(self.cx), abs(self.cy)) / step > 1e12:  # lines would not advance in float
            return
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

    def arrow(self, start: Point, end: Point, color: tuple[int, int, int], width: int = 2, head: float = 8.0) -> None:
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

    def text(self, lines: Sequence[str], pos: Point = (8.0, 6.0)) -> None:
        if self.font is None:
            return
        y = pos[1]
        for line in lines:
            img = self.font.render(line, True, _TEXT)
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


def _fmt(v: float) -> str:
    return f"{v: .3e}" if math.isfinite(v) else str(v)


class FlockingRenderer:
    """Particles in the xz-plane; the camera follows the group.

    The view is centred on the centroid of the (finite) particle positions and scaled so that
    every particle fits with a margin (at least 30 m across).  Followers are blue, the leader
    red; each particle carries an arrow along its velocity, of length proportional to its speed
    divided by the largest speed (the longest is 60 px); a grey line through each follower shows
    the leader's direction (the constraint asks the follower's arrow to lie on it).  The
    ``phi`` values are written in the corner when ``pygame.font`` is available.
    """

    def __init__(self, n_agents: int, render_mode: str, fps: float = 20) -> None:
        if int(n_agents) != n_agents or n_agents < 2:
            raise ValueError(f"n_agents must be an integer >= 2, got {n_agents!r}")
        self.n_agents = int(n_agents)
        self._canvas = _Canvas(render_mode, fps, "FlockingAlign")
        self.render_mode = render_mode

    def draw(self, state: NDArray[np.float64], phi: NDArray[np.float64]) -> NDArray[np.uint8] | None:
        c = self._canvas
        pg = c.pg
        n = self.n_agents
        s = np.asarray(state, dtype=np.float64).reshape(4, n)
        x, z, vx, vz = s
        c.surf.fill(_BG)
        ok = np.isfinite(x) & np.isfinite(z)
        if ok.any():
            with np.errstate(all="ignore"):
                cx, cz = float(np.mean(x[ok])), float(np.mean(z[ok]))
                half = float(max(np.max(np.abs(x[ok] - cx)), np.max(np.abs(z[ok] - cz)), 10.0)) * 1.5
            scale = c.size / (2.0 * half) if _finite(cx, cz, half) and half > 0 else 1.0
            c.view(cx if math.isfinite(cx) else 0.0, cz if math.isfinite(cz) else 0.0, scale)
        else:
            c.view(0.0, 0.0, 1.0)
        c.grid()
        with np.errstate(all="ignore"):
            speed = np.hypot(vx, vz)
        fin_speed = speed[np.isfinite(speed)]
        vmax = float(fin_speed.max()) if fin_speed.size else 0.0
        lead = n - 1
        lvx, lvz, lsp = float(vx[lead]), float(vz[lead]), float(speed[lead])
        for i in range(n):
            if not ok[i]:
                continue
            p = c.px(float(x[i]), float(z[i]))
            if i != lead and _finite(lvx, lvz, lsp) and lsp > 0:
                ex, ey = 45.0 * lvx / lsp, -45.0 * lvz / lsp
                pg.draw.line(c.surf, _GUIDE, (p[0] - ex, p[1] - ey), (p[0] + ex, p[1] + ey), 1)
        for i in range(n):
            if not ok[i]:
                continue
            p = c.px(float(x[i]), float(z[i]))
            color = _LEADER if i == lead else _FOLLOWER
            sp_i = float(speed[i])
            if _finite(sp_i) and sp_i > 0 and vmax > 0:
                length = 60.0 * sp_i / vmax
                tip = (p[0] + length * float(vx[i]) / sp_i, p[1] - length * float(vz[i]) / sp_i)
                c.arrow(p, tip, color)
            pg.draw.circle(c.surf, color, (int(round(p[0])), int(round(p[1]))), 7 if i == lead else 6)
        ph = np.asarray(phi, dtype=np.float64).ravel()
        lines = ["phi_" + str(b + 1) + " =" + _fmt(float(v)) for b, v in enumerate(ph)]
        if math.isfinite(c.scale) and c.scale > 0:
            lines.append(f"grid {_nice_step(50.0 / c.scale):g} m")
        c.text(lines)
        return c.show()

    def close(self) -> None:
        self._canvas.close()


class USVRenderer:
    """The boat from above, in a 20 m wide view centred on it.

    A quiver grid of the current (2 m spacing, fixed to the world, so it slides past as the
    boat moves; arrows scaled by the largest current in view, at least 1 m/s), the hull as an
    oriented triangle pointing along ``theta``, the boat's velocity (red) and its velocity
    relative to the water (green; the constraint asks it to point along the hull), both at
    2 m per m/s (capped at 9 m).  ``phi`` is written in the corner when ``pygame.font`` is available.
    """

    view_width = 20.0  #: metres across the frame
    spacing = 2.0  #: metres between quiver arrows
    arrow_scale = 2.0  #: metres of arrow per m/s of velocity

    def __init__(self, render_mode: str, fps: float = 20) -> None:
        self._canvas = _Canvas(render_mode, fps, "vnhc_gym")
        self.render_mode = render_mode

    def _tip(self, x: float, y: float, vx: float, vy: float) -> Point:
        """Tip of a velocity arrow from ``(x, y)``: ``arrow_scale`` m per m/s, at most 0.45 view widths."""
        length = math.hypot(vx, vy) * self.arrow_scale
        k = self.arrow_scale if length <= 0.45 * self.view_width else 0.45 * self.view_width / math.hypot(vx, vy)
        return x + k * vx, y + k * vy

    def _quiver(self, current: Callable[[Any, Any], Any]) -> None:
        c = self._canvas
        half = self.view_width / 2.0 + self.spacing
        h = self.spacing
        if max(abs(c.cx), abs(c.cy)) > 1e12:  # grid points would not be distinct in float
            return
        xs = h * np.arange(math.floor((c.cx - half) / h), math.ceil((c.cx + half) / h) + 1)
        ys = h * np.arange(math.floor((c.cy - half) / h), math.ceil((c.cy + half) / h) + 1)
        gx, gy = np.meshgrid(xs, ys)
        try:
            with np.errstate(all="ignore"):
                vel = np.asarray(current(gx, gy), dtype=np.float64)
        except (ArithmeticError, ValueError, TypeError):
            return
        if vel.shape != (*gx.shape, 2):
            return
        with np.errstate(all="ignore"):
            mag = np.hypot(vel[..., 0], vel[..., 1])
        good = np.isfinite(mag)
        if not good.any():
            return
        norm = max(float(mag[good].max()), 1.0)
        for j, i in zip(*np.nonzero(good), strict=True):
            x0, y0 = float(gx[j, i]), float(gy[j, i])
            u, v = float(vel[j, i, 0]), float(vel[j, i, 1])
            k = 0.8 * h / norm
            a = c.px(x0 - 0.5 * k * u, y0 - 0.5 * k * v)
            b = c.px(x0 + 0.5 * k * u, y0 + 0.5 * k * v)
            c.arrow(a, b, _CURRENT, width=1, head=6.0)

    def draw(self, state: NDArray[np.float64], phi: NDArray[np.float64],
             current: Callable[[Any, Any], Any]) -> NDArray[np.uint8] | None:
        c = self._canvas
        pg = c.pg
        x, y, th, xd, yd, _ = (float(v) for v in np.asarray(state, dtype=np.float64).ravel()[:6])
        c.surf.fill(_WATER)
        centred = _finite(x, y)
        c.view(x if centred else 0.0, y if centred else 0.0, c.size / self.view_width)
        c.grid()
        self._quiver(current)
        if centred and math.isfinite(th):
            ct, st = math.cos(th), math.sin(th)
            # Hull: 2.4 m long, 1.0 m wide, bow along (cos th, sin th).
            pts = [(1.4, 0.0), (-1.0, 0.5), (-0.7, 0.0), (-1.0, -0.5)]
            hull = [c.px(x + a * ct - b * st, y + a * st + b * ct) for a, b in pts]
            pg.draw.polygon(c.surf, _HULL, hull)
            pg.draw.polygon(c.surf, (0, 0, 0), hull, 1)
        water = np.full(2, np.nan)
        if centred:
            try:
                with np.errstate(all="ignore"):
                    water = np.asarray(current(np.array([x]), np.array([y])), dtype=np.float64).reshape(-1)[:2]
            except (ArithmeticError, ValueError, TypeError):
                water = np.full(2, np.nan)
            origin = c.px(x, y)
            if _finite(xd, yd):
                c.arrow(origin, c.px(*self._tip(x, y, xd, yd)), _VEL, width=3)
                if water.shape == (2,) and np.all(np.isfinite(water)):
                    rx, ry = xd - float(water[0]), yd - float(water[1])
                    c.arrow(origin, c.px(*self._tip(x, y, rx, ry)), _REL, width=3)
        ph = np.asarray(phi, dtype=np.float64).ravel()
        lines = [f"phi ={_fmt(float(ph[0]))} m/s" if ph.size else "phi = ?",
                 f"x = {x:.2f} m, y = {y:.2f} m" if centred else "position not finite",
                 "red: velocity, green: relative to water"]
        c.text(lines)
        return c.show()

    def close(self) -> None:
        self._canvas.close()
