"""Top-down pygame renderer for a :class:`~swarm_env.state.WorldState`.

The picture follows the figures of the two papers the project reproduces:
white background with a light 1 m grid, the world walls as a dark border,
static obstacles filled gray, the leader's path as a thin dashed line, the
leader as a black dot (virtual) or black disc (robot), humans as orange discs
with a velocity arrow, followers as coloured discs with a heading line, each
follower's slot target as a light disc of the same colour (paper 000, Fig. 2),
short fading trails, a red ring on robots that touched something in the last
few steps, and a one-line header (time, formation shape, collisions so far).

pygame is imported lazily inside methods: ``import swarm_env.render`` never
imports pygame and ``rgb_array`` mode never initialises the display. A
:class:`Renderer` drops every pygame object when pickled or deep-copied and
recreates them on the next :meth:`Renderer.render`, so an env holding one
stays picklable.

Pixel frame: origin at the image's top-left corner, x to the right, y down.
World frame: metres, origin at the world's bottom-left corner, y up.
"""

from __future__ import annotations

import math
import os
from typing import TYPE_CHECKING, Any

import numpy as np

from swarm_env.scenario import Scenario

if TYPE_CHECKING:  # only for annotations: keeps this module's import light
    from swarm_env.state import WorldState

RENDER_MODES = ("human", "rgb_array")

Colour = tuple[int, int, int]

#: Follower colours, by follower index (cycled). matplotlib's tab10 without its
#: orange (humans), red (contacts) and gray (obstacles), completed with three
#: darker tab20b tones so that 10 followers get 10 distinct colours.
FOLLOWER_COLOURS: tuple[Colour, ...] = (
    (31, 119, 180),  # blue
    (44, 160, 44),  # green
    (148, 103, 189),  # purple
    (140, 86, 75),  # brown
    (227, 119, 194),  # pink
    (188, 189, 34),  # olive
    (23, 190, 207),  # cyan
    (57, 59, 121),  # navy
    (99, 121, 57),  # moss
    (123, 65, 115),  # plum
)

BACKGROUND: Colour = (255, 255, 255)
GRID_MINOR: Colour = (236, 236, 236)
GRID_MAJOR: Colour = (218, 218, 218)
WALL: Colour = (45, 45, 45)
OBSTACLE_FILL: Colour = (160, 160, 160)
OBSTACLE_EDGE: Colour = (115, 115, 115)
PATH: Colour = (110, 110, 110)
LEADER: Colour = (15, 15, 15)
HUMAN_FILL: Colour = (245, 150, 50)
HUMAN_EDGE: Colour = (190, 100, 20)
HUMAN_ARROW: Colour = (200, 95, 10)
CONTACT: Colour = (225, 25, 25)
TEXT: Colour = (25, 25, 25)
TEXT_DIM: Colour = (120, 120, 120)

#: A robot keeps its red contact ring for this many recorded steps after a contact.
FLASH_STEPS = 3
#: Human velocity arrows show where the human will be in this many seconds.
ARROW_SECONDS = 1.5
#: Leader path dash and gap lengths (m).
DASH_M, GAP_M = 0.3, 0.2


def follower_colour(i: int) -> Colour:
    """The fixed colour of follower ``i`` (cycles after ``len(FOLLOWER_COLOURS)``)."""
    return FOLLOWER_COLOURS[i % len(FOLLOWER_COLOURS)]


def _mix(c: Colour, weight: float, other: Colour = BACKGROUND) -> Colour:
    """``weight * c + (1 - weight) * other``, as integer RGB."""
    return tuple(int(round(weight * a + (1.0 - weight) * b)) for a, b in zip(c, other))  # type: ignore[return-value]


def _even(n: float) -> int:
    """Round up to an even integer: H.264 with yuv420p needs even frame sides."""
    k = int(math.ceil(n))
    return k + (k % 2)


def _import_pygame() -> Any:
    os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")
    import pygame  # noqa: PLC0415 - lazy on purpose, see module docstring

    return pygame


def window_driver_missing() -> str | None:
    """Why a ``"human"`` window cannot be shown here, or ``None`` when it can.

    With no display SDL falls back to a driver that draws nowhere (``offscreen`` or ``dummy``), and a
    "window" would play the episode unseen. A driver chosen on purpose (``SDL_VIDEODRIVER``, e.g. ``dummy``
    in headless tests) is respected."""
    if os.environ.get("SDL_VIDEODRIVER"):
        return None
    pg = _import_pygame()
    was_init = pg.display.get_init()
    saved = os.dup(2)  # SDL prints its own complaints (XDG_RUNTIME_DIR, ...) to fd 2: keep them off the terminal
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 2)
            try:
                pg.display.init()
                driver = pg.display.get_driver()
            except pg.error as exc:
                return f"no video driver could start ({exc})"
            finally:
                if not was_init:
                    pg.display.quit()
    finally:
        os.dup2(saved, 2)
        os.close(saved)
    if driver in ("offscreen", "dummy"):
        return f"no display (SDL chose its {driver!r} driver, which shows nothing)"
    return None


def _circle(pg: Any) -> Any:
    """pygame-ce >= 2.5's anti-aliased ``draw.aacircle``, else the plain ``draw.circle`` (same signature)."""
    return getattr(pg.draw, "aacircle", pg.draw.circle)


def _dashes(points: np.ndarray, dash: float, gap: float) -> list[np.ndarray]:
    """Split the polyline ``points`` (P, 2) into dashes of length ``dash`` separated by ``gap``.

    Lengths are in the units of ``points``. Returns one ``(k, 2)`` polyline per
    dash (a dash keeps the path's vertices it spans, so it bends with the path).
    """
    points = np.asarray(points, dtype=np.float64)
    cum = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(points, axis=0).T))])
    total = float(cum[-1])
    out: list[np.ndarray] = []
    if total <= 0.0:
        return out
    for a in np.arange(0.0, total, dash + gap):
        b = min(a + dash, total)
        inner = (cum > a) & (cum < b)
        s = np.concatenate([[a], cum[inner], [b]])
        out.append(np.column_stack([np.interp(s, cum, points[:, 0]), np.interp(s, cum, points[:, 1])]))
    return out


class Renderer:
    """Draws a :class:`WorldState` with pygame.

    Args:
        mode: ``"human"`` (a pygame window, created on the first
            :meth:`render`) or ``"rgb_array"`` (:meth:`render` returns pixels).
        scenario: sets the world size, hence the image size. Rendering a state
            of a scenario with another world size re-lays the image out.
        pixels_per_metre: the scale; ``None`` chooses it so that the image's
            larger side is ``max_size`` pixels.
        max_size: see ``pixels_per_metre``.
        trail_length: how many recorded positions each robot's trail keeps.
        fps: ``"human"`` mode frame rate limit; ``None`` means real time
            (``1 / scenario.world.dt``).

    Use: :meth:`reset` at the start of an episode, :meth:`record` after reset
    and after every step (cheap: it stores positions and counts contacts), and
    :meth:`render` whenever a picture is wanted.

    Attributes: ``scenario`` (the one the layout was made for), ``size``,
    ``pixels_per_metre``, ``fps``, ``collisions`` (contact onsets recorded
    since :meth:`reset`).

    The image is ``size = (width, height)`` pixels, both even: the world
    rectangle with a small margin (where the walls are drawn) and a header
    line of text above it.
    """

    def __init__(
        self,
        mode: str,
        scenario: Scenario,
        pixels_per_metre: float | None = None,
        max_size: int = 800,
        trail_length: int = 40,
        fps: int | None = None,
    ) -> None:
        if mode not in RENDER_MODES:
            raise ValueError(f"render mode must be one of {RENDER_MODES}, got {mode!r}")
        if pixels_per_metre is not None and not pixels_per_metre > 0:
            raise ValueError(f"pixels_per_metre must be > 0, got {pixels_per_metre!r}")
        if max_size < 64:
            raise ValueError(f"max_size must be >= 64 pixels, got {max_size!r}")
        if trail_length < 0:
            raise ValueError(f"trail_length must be >= 0, got {trail_length!r}")
        self.mode = mode
        self.max_size = int(max_size)
        self.trail_length = int(trail_length)
        self._fixed_ppm = pixels_per_metre
        self._fps = fps
        self._layout(scenario)
        self.reset()
        self._init_pygame_fields()

    # ------------------------------------------------------------------ layout
    def _layout(self, scenario: Scenario) -> None:
        """Choose the scale and the image size for ``scenario``'s world."""
        self.scenario = scenario
        w, h = (float(v) for v in scenario.world.size)
        base = self._fixed_ppm if self._fixed_ppm is not None else self.max_size / max(w, h)
        # Margin and header scale with the image so small renders stay readable.
        ref = max(w, h) * base
        self.margin = max(6, int(round(0.015 * ref)))
        self.header = max(16, int(round(0.035 * ref)))
        if self._fixed_ppm is None:
            ppm = min((self.max_size - 2 * self.margin) / w, (self.max_size - 2 * self.margin - self.header) / h)
        else:
            ppm = float(self._fixed_ppm)
        self.pixels_per_metre = float(ppm)
        self.world_size = (w, h)
        self.size = (_even(w * ppm + 2 * self.margin), _even(h * ppm + 2 * self.margin + self.header))
        self.fps = float(self._fps) if self._fps is not None else 1.0 / float(scenario.world.dt)
        # world rectangle in pixels
        self._ox = float(self.margin)
        self._oy = float(self.header + self.margin)

    def world_to_pixels(self, xy: np.ndarray) -> np.ndarray:
        """World points ``(..., 2)`` in metres to pixel coordinates ``(..., 2)`` (float, y down)."""
        xy = np.asarray(xy, dtype=np.float64)
        out = np.empty_like(xy)
        out[..., 0] = self._ox + xy[..., 0] * self.pixels_per_metre
        out[..., 1] = self._oy + (self.world_size[1] - xy[..., 1]) * self.pixels_per_metre
        return out

    # ------------------------------------------------------------------ pygame objects
    def _init_pygame_fields(self) -> None:
        self._canvas: Any = None  # the frame surface, drawing into _canvas_px
        self._canvas_px: np.ndarray | None = None  # (H, W, 3) uint8
        self._static_px: np.ndarray | None = None  # (H, W, 3): background, grid, walls, obstacles, leader path
        self._static_key: tuple[Any, Any] | None = None  # (StaticMap, Scenario) the layer was drawn for
        self._window: Any = None
        self._clock: Any = None
        self._font: Any = None
        self._font_failed = False

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        for key in ("_canvas", "_canvas_px", "_static_px", "_static_key", "_window", "_clock", "_font"):
            state[key] = None
        state["_font_failed"] = False
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)

    # ------------------------------------------------------------------ recording
    def reset(self) -> None:
        """Forget the trails, the contact flashes and the collision count."""
        self._trail: np.ndarray | None = None  # (L, R, 2) ring buffer, R = followers + leader
        self._trail_head = 0
        self._trail_count = 0
        self._n_recorded = 0
        self._last_contact: np.ndarray | None = None  # (R,) record index of each robot's last contact
        self.collisions = 0

    def record(self, state: WorldState) -> None:
        """Append the robots' positions to the trails and count the step's contacts."""
        n = state.n_followers
        n_robots = n + 1  # the leader (index n here) gets a trail too
        if self._trail is None or self._trail.shape[1] != n_robots:
            self._trail = np.full((max(self.trail_length, 1), n_robots, 2), np.nan)
            self._trail_head = 0
            self._trail_count = 0
            self._last_contact = np.full(n_robots, -(10**9), dtype=np.int64)
        if self.trail_length > 0:
            self._trail[self._trail_head, :n] = state.follower_pose[:, :2]
            self._trail[self._trail_head, n] = state.leader_pose[:2]
            self._trail_head = (self._trail_head + 1) % self.trail_length
            self._trail_count = min(self._trail_count + 1, self.trail_length)
        self._n_recorded += 1
        if state.contacts:
            self.collisions += len(state.contacts)
            for i in self._contact_robots(state, n):
                self._last_contact[i] = self._n_recorded  # type: ignore[index]

    @staticmethod
    def _contact_robots(state: WorldState, n: int) -> set[int]:
        """Row indices (followers 0..n-1, leader n) of the robots in ``state.contacts``."""
        rows: set[int] = set()
        for c in state.contacts:
            rows.add(n if c.robot < 0 else c.robot)
            if c.kind == "robot_robot":
                rows.add(n if c.other < 0 else c.other)
        return {r for r in rows if 0 <= r <= n}

    # ------------------------------------------------------------------ drawing
    def render(self, state: WorldState) -> np.ndarray | None:
        """Draw ``state``.

        Returns a fresh ``(height, width, 3)`` uint8 RGB array in
        ``"rgb_array"`` mode; in ``"human"`` mode draws to the window (pumping
        its events and limiting the rate to ``fps``) and returns ``None``.
        """
        pg = _import_pygame()
        if tuple(float(v) for v in state.scenario.world.size) != self.world_size:
            self._layout(state.scenario)
        w, h = self.size
        if self._canvas is None or self._canvas_px is None or self._canvas_px.shape != (h, w, 3):
            # The canvas surface draws straight into a numpy array we own (24-bit RGB, rows
            # contiguous): clearing it is one memcpy from the static layer and returning it is
            # one more, where pygame.image.tobytes plus a copy cost ~10x as much.
            self._canvas_px = np.empty((h, w, 3), dtype=np.uint8)
            self._canvas = pg.image.frombuffer(self._canvas_px, (w, h), "RGB")
            self._static_px = None
        key = (state.static, state.scenario)
        if self._static_px is None or self._static_key is None or any(a is not b for a, b in zip(key, self._static_key)):
            layer = self._draw_static(pg, state)
            self._static_px = np.frombuffer(pg.image.tobytes(layer, "RGB"), dtype=np.uint8).reshape(h, w, 3)
            self._static_key = key
        assert self._static_px is not None and self._canvas_px is not None

        np.copyto(self._canvas_px, self._static_px)
        canvas = self._canvas
        self._draw_dynamic(pg, canvas, state)
        self._draw_text(pg, canvas, state)

        if self.mode == "rgb_array":
            return self._canvas_px.copy()
        self._show(pg, canvas)
        return None

    def _draw_static(self, pg: Any, state: WorldState) -> Any:
        """The layer that does not change during an episode."""
        surf = pg.Surface(self.size)
        surf.fill(BACKGROUND)
        s = self.pixels_per_metre
        w, h = self.world_size
        x0, y0 = self._ox, self._oy
        x1, y1 = x0 + w * s, y0 + h * s
        # Grid: 1 m, thinned out when the lines would be too dense to read.
        step = 1.0 if s >= 8 else (5.0 if s >= 1.6 else 10.0)
        for k in range(1, int(math.floor(w / step + 1e-9)) + 1):
            x = x0 + k * step * s
            if x < x1 - 0.5:
                major = (k * step) % 5 == 0
                pg.draw.line(surf, GRID_MAJOR if major else GRID_MINOR, (x, y0), (x, y1))
        for k in range(1, int(math.floor(h / step + 1e-9)) + 1):
            y = y1 - k * step * s
            if y > y0 + 0.5:
                major = (k * step) % 5 == 0
                pg.draw.line(surf, GRID_MAJOR if major else GRID_MINOR, (x0, y), (x1, y))
        # Walls: a dark frame just outside the world rectangle.
        t = max(2, min(self.margin - 2, int(round(0.1 * s))))
        pg.draw.rect(surf, WALL, pg.Rect(round(x0) - t, round(y0) - t, round(w * s) + 2 * t, round(h * s) + 2 * t), t)
        # Obstacles.
        static = state.static
        for poly in static.polygons:
            pts = self.world_to_pixels(np.asarray(poly, dtype=np.float64)).tolist()
            if len(pts) >= 3:
                pg.draw.polygon(surf, OBSTACLE_FILL, pts)
                pg.draw.aalines(surf, OBSTACLE_EDGE, True, pts)
        circles = np.asarray(static.circles, dtype=np.float64).reshape(-1, 3)
        for (cx, cy), r in zip(self.world_to_pixels(circles[:, :2]).tolist(), (circles[:, 2] * s).tolist()):
            _circle(pg)(surf, OBSTACLE_FILL, (cx, cy), max(r, 1.0))
            if r >= 3:
                _circle(pg)(surf, OBSTACLE_EDGE, (cx, cy), r, 1)
        # The leader's path: dashed, with a small ring on its end.
        path = np.asarray(state.scenario.leader.path, dtype=np.float64).reshape(-1, 2)
        if len(path) >= 2:
            pix = self.world_to_pixels(path)
            width = 2 if s >= 30 else 1
            for dash in _dashes(pix, max(DASH_M * s, 3.0), max(GAP_M * s, 2.0)):
                for a, b in zip(dash[:-1].tolist(), dash[1:].tolist()):
                    pg.draw.aaline(surf, PATH, a, b, width)
            _circle(pg)(surf, PATH, pix[-1].tolist(), max(3.0, 0.12 * s), 1)
        return surf

    def _draw_dynamic(self, pg: Any, surf: Any, state: WorldState) -> None:
        s = self.pixels_per_metre
        n = state.n_followers
        colours = [follower_colour(i) for i in range(n)]

        # Trails: each in up to four pieces getting darker towards the robot, so it fades out behind.
        if self._trail is not None and self._trail_count >= 2 and self._trail.shape[1] == n + 1:
            idx = (self._trail_head - self._trail_count + np.arange(self._trail_count)) % self._trail.shape[0]
            trail = self.world_to_pixels(self._trail[idx])  # (T, R, 2), oldest first
            pieces = min(4, self._trail_count - 1)
            bounds = np.linspace(0, self._trail_count - 1, pieces + 1).round().astype(int)
            for r in range(n + 1):
                base = colours[r] if r < n else LEADER
                if r == n and not state.leader_is_robot and state.leader_radius <= 0:
                    continue  # a virtual leader's trail is its dashed path
                for p in range(pieces):
                    seg = trail[bounds[p] : bounds[p + 1] + 1, r]
                    seg = seg[np.isfinite(seg).all(axis=1)]
                    if len(seg) >= 2:
                        pg.draw.aalines(surf, _mix(base, 0.2 + 0.6 * (p + 1) / pieces), False, seg.tolist())

        # Slot targets: light discs of the follower's colour (paper 000, Fig. 2).
        if n:
            slots = self.world_to_pixels(state.slot_targets).tolist()
            radii = np.maximum(np.asarray(state.follower_radius) * s, 2.0).tolist()
            for i in range(n):
                _circle(pg)(surf, _mix(colours[i], 0.25), slots[i], radii[i])
                _circle(pg)(surf, _mix(colours[i], 0.5), slots[i], radii[i], 1)

        # Humans with velocity arrows.
        if len(state.human_pos):
            hp = self.world_to_pixels(state.human_pos)
            tips = self.world_to_pixels(np.asarray(state.human_pos) + ARROW_SECONDS * np.asarray(state.human_vel))
            hr = np.maximum(np.asarray(state.human_radius) * s, 2.0)
            for (cx, cy), (tx, ty), r in zip(hp.tolist(), tips.tolist(), hr.tolist()):
                _circle(pg)(surf, HUMAN_FILL, (cx, cy), r)
                _circle(pg)(surf, HUMAN_EDGE, (cx, cy), r, 1)
                self._arrow(pg, surf, HUMAN_ARROW, (cx, cy), (tx, ty))

        flashing = {i for i in range(n + 1) if self._flashing(i)} | self._contact_robots(state, n)

        # Leader.
        lp = self.world_to_pixels(state.leader_pose[:2]).tolist()
        if state.leader_radius > 0:
            lr = max(state.leader_radius * s, 3.0)
            _circle(pg)(surf, LEADER, lp, lr)
            self._heading(pg, surf, lp, lr, float(state.leader_pose[2]))
            if n in flashing:
                _circle(pg)(surf, CONTACT, lp, lr + 3, 3)
        else:
            _circle(pg)(surf, LEADER, lp, max(0.12 * s, 4.0))

        # Followers: disc, darker rim, heading line.
        if n:
            pos = self.world_to_pixels(state.follower_pose[:, :2]).tolist()
            radii = np.maximum(np.asarray(state.follower_radius) * s, 2.0).tolist()
            thetas = np.asarray(state.follower_pose[:, 2]).tolist()
            for i in range(n):
                _circle(pg)(surf, colours[i], pos[i], radii[i])
                _circle(pg)(surf, _mix(colours[i], 0.6, (0, 0, 0)), pos[i], radii[i], 1)
                self._heading(pg, surf, pos[i], radii[i], thetas[i])
                if i in flashing:
                    _circle(pg)(surf, CONTACT, pos[i], radii[i] + 3, 3)

    def _flashing(self, row: int) -> bool:
        if self._last_contact is None or row >= len(self._last_contact):
            return False
        return bool(self._n_recorded - self._last_contact[row] < FLASH_STEPS)

    @staticmethod
    def _heading(pg: Any, surf: Any, centre: list[float], r: float, theta: float) -> None:
        """A white line from the centre to the rim of a disc, pointing along ``theta`` (world frame)."""
        if r < 4:
            return
        tip = (centre[0] + 0.9 * r * math.cos(theta), centre[1] - 0.9 * r * math.sin(theta))
        pg.draw.aaline(surf, BACKGROUND, centre, tip, max(1, int(round(r * 0.18))))

    @staticmethod
    def _arrow(pg: Any, surf: Any, colour: Colour, a: tuple[float, float], b: tuple[float, float]) -> None:
        dx, dy = b[0] - a[0], b[1] - a[1]
        length = math.hypot(dx, dy)
        if length < 3:
            return
        ux, uy = dx / length, dy / length
        head = min(8.0, 0.4 * length)
        pg.draw.aaline(surf, colour, a, b, 2)
        left = (b[0] - head * (ux - 0.5 * uy), b[1] - head * (uy + 0.5 * ux))
        right = (b[0] - head * (ux + 0.5 * uy), b[1] - head * (uy - 0.5 * ux))
        pg.draw.polygon(surf, colour, [b, left, right])

    def _draw_text(self, pg: Any, surf: Any, state: WorldState) -> None:
        font = self._get_font(pg)
        if font is None:
            return
        formations = state.scenario.formations
        if 0 <= state.formation_index < len(formations):
            shape = f"{formations[state.formation_index].shape} ({state.formation_index + 1}/{len(formations)})"
        else:
            shape = "-"
        left = f"t = {state.time:.1f} s    formation: {shape}    collisions: {self.collisions}"
        if state.leader_done:
            left += "    leader done"
        try:
            img = font.render(left, True, TEXT)
            y = (self.header + self.margin - img.get_height()) // 2 + 1
            surf.blit(img, (self.margin, y))
            name = font.render(state.scenario.name, True, TEXT_DIM)
            x = self.size[0] - self.margin - name.get_width()
            if x > self.margin + img.get_width() + 10:
                surf.blit(name, (x, y))
        except Exception:  # noqa: BLE001 - text is decoration: never let it break a rollout
            self._font, self._font_failed = None, True

    def _get_font(self, pg: Any) -> Any:
        if self._font_failed:
            return None
        try:
            if not pg.font.get_init():
                pg.font.init()
                self._font = None  # a font from before a font.quit() is dead
            if self._font is None:
                self._font = pg.font.Font(None, max(12, int(round(self.header * 0.8))))
        except Exception:  # noqa: BLE001 - no SDL_ttf or no default font: draw without text
            self._font, self._font_failed = None, True
        return self._font

    def _show(self, pg: Any, canvas: Any) -> None:
        if self._window is None or not pg.display.get_init() or pg.display.get_surface() is not self._window:
            pg.display.init()
            self._window = pg.display.set_mode(self.size)
            pg.display.set_caption("swarm-env")
            self._clock = pg.time.Clock()
        elif self._window.get_size() != self.size:
            self._window = pg.display.set_mode(self.size)
        pg.event.pump()  # keeps the window responsive; the env has no use for the events
        self._window.blit(canvas, (0, 0))
        pg.display.flip()
        if self.fps > 0:
            self._clock.tick(self.fps)

    def close(self) -> None:
        """Close the window (if this renderer opened one) and drop every pygame object."""
        if self._window is not None:
            pg = _import_pygame()
            if pg.display.get_init():
                pg.display.quit()
        # pygame.quit() is not called: other renderers in this process may still use pygame.font.
        self._init_pygame_fields()
