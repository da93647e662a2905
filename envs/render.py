"""Top-down rendering of odomgym's envs with pygame (the ``render`` extra).

Imported only when an env renders (an env made with ``render_mode=None`` never imports it, so
pygame stays optional and an env that does not render does no drawing work).

One style for every env: a light floor with a 1 m (or 5 m) grid, the planned path in grey, the
ground truth in blue, the odometry in orange, a corrected estimate (IPEC) in green; vehicles as
outlines (solid at the true pose, thin at the estimated one) with a black nose line; a legend in
a header band above the floor (never over the paths) and a scale bar at the bottom left.

* :class:`TopDownRenderer` — a route env (``UMBmarkSquare-v0``, ``StraightLine-v0``);
* :class:`VehicleRenderer` — the two-truck vehicles (``ClapperStraight-v0``,
  ``ClapperRectangle-v0``, the CLAPPER or the encoder trailer);
* :class:`SessionRenderer` — ``SelfCalibration-v1``: the runs of the session so far, overlaid
  in their start frames, beside a panel of the estimates and the budget.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from odomgym.floor import CableBump, FloorSpec
from odomgym.robot import RobotSpec
from odomgym.sim.routes import Route

try:
    import pygame
except ImportError as exc:  # pragma: no cover - depends on the environment
    raise ImportError("rendering needs pygame: pip install 'odomgym[render]'") from exc

__all__ = [
    "ESTIMATE",
    "ODOM_PATH",
    "ODOM_PATH_B",
    "ROUTE",
    "TRUE_PATH",
    "SessionRenderer",
    "SessionRun",
    "TopDownRenderer",
    "VehicleRenderer",
    "VehicleTrace",
]

SIZE = 600
BACKGROUND = (245, 245, 240)
GRID = (225, 225, 220)
ROUTE = (170, 170, 170)
TRUE_PATH = (31, 119, 180)
ODOM_PATH = (255, 127, 14)
ODOM_PATH_B = (148, 103, 189)
ESTIMATE = (44, 160, 44)
LINK = (60, 60, 60)
LINK_AT_STOP = (214, 39, 40)
BUMP = (90, 60, 40)
WHEEL = (40, 40, 40)
PATCH = (200, 225, 240)
TEXT = (40, 40, 40)
HEADER = (255, 255, 255)
FADED_TRUE = (160, 190, 215)
FADED_ODOM = (245, 200, 160)

Pixel = tuple[int, int]
ToPixel = Callable[[float, float], Pixel]


class _Canvas:
    """A pygame surface, the window of ``"human"`` mode, fonts and the shared drawing helpers.

    ``present`` turns the drawn surface into what ``render()`` returns: an (H, W, 3) uint8 frame
    for ``"rgb_array"``, or None after showing it (and waiting a frame period) for ``"human"``.
    """

    def __init__(self, mode: str, fps: float, width: int, height: int, caption: str) -> None:
        self.mode, self.fps = mode, fps
        self.width, self.height = width, height
        pygame.font.init()
        self.font = pygame.font.Font(None, 18)
        self.big_font = pygame.font.Font(None, 24)
        if mode == "human":
            pygame.display.init()
            self.window: Any = pygame.display.set_mode((width, height))
            pygame.display.set_caption(caption)
        else:
            self.window = None
        self.surface = pygame.Surface((width, height))
        self.clock = pygame.time.Clock()

    def present(self) -> NDArray[np.uint8] | None:
        if self.mode == "human":
            assert self.window is not None
            self.window.blit(self.surface, (0, 0))
            pygame.event.pump()
            pygame.display.flip()
            self.clock.tick(self.fps)
            return None
        return np.transpose(np.array(pygame.surfarray.pixels3d(self.surface)), (1, 0, 2)).copy()

    def text(self, words: str, at: Pixel, colour: Any = TEXT, big: bool = False) -> int:
        """Draw ``words`` with its top-left at ``at``; returns its width [px]."""
        image = (self.big_font if big else self.font).render(words, True, colour)
        self.surface.blit(image, at)
        return int(image.get_width())

    def legend(
        self, entries: Sequence[tuple[Any, str]], left: int, top: int, width: int, columns: int
    ) -> None:
        """A key of coloured line samples and labels, ``columns`` per row, from (left, top)."""
        column_width = width // columns
        for k, (colour, label) in enumerate(entries):
            x = left + (k % columns) * column_width
            y = top + 18 * (k // columns)
            pygame.draw.line(self.surface, colour, (x, y + 6), (x + 24, y + 6), 3)
            self.text(label, (x + 30, y))

    def scale_bar(self, scale: float, left: int, bottom: int, view_width: int) -> None:
        """A bar of a round length (1, 2 or 5 × 10^k m) about a sixth of the view."""
        target = view_width / 6 / scale
        power = 10.0 ** math.floor(math.log10(target))
        length = max(m * power for m in (1.0, 2.0, 5.0) if m * power <= target)
        pixels = round(length * scale)
        y = bottom - 20
        surf = self.surface
        pygame.draw.line(surf, TEXT, (left + 10, y), (left + 10 + pixels, y), 3)
        for x in (left + 10, left + 10 + pixels):
            pygame.draw.line(surf, TEXT, (x, y - 5), (x, y + 5), 2)
        label = f"{length:g} m" if length >= 1.0 else f"{length * 100:g} cm"
        self.text(label, (left + 14 + pixels, y - 8))

    def grid(self, to_px: ToPixel, view: _View) -> None:
        """Grid lines every 1 m (every 5 m when the view spans 20 m or more)."""
        step = 1.0 if view.span < 20 else 5.0
        x0, x1, y0, y1 = view.world_bounds()
        for k in range(math.floor(x0 / step), math.ceil(x1 / step) + 1):
            pygame.draw.line(self.surface, GRID, to_px(k * step, y0), to_px(k * step, y1))
        for k in range(math.floor(y0 / step), math.ceil(y1 / step) + 1):
            pygame.draw.line(self.surface, GRID, to_px(x0, k * step), to_px(x1, k * step))

    def floor(self, to_px: ToPixel, floor: FloorSpec, extra: Sequence[CableBump] = ()) -> None:
        """Friction patches (light blue) and cables or bumps (brown lines)."""
        surf = self.surface
        for patch in floor.patches:
            left, top = to_px(patch.x_min, patch.y_max)
            right, bottom = to_px(patch.x_max, patch.y_min)
            pygame.draw.rect(surf, PATCH, pygame.Rect(left, top, right - left, bottom - top))
        for bump in (*floor.bumps, *extra):
            dx = 0.5 * bump.length * math.cos(bump.angle)
            dy = 0.5 * bump.length * math.sin(bump.angle)
            pygame.draw.line(
                surf, BUMP, to_px(bump.x - dx, bump.y - dy), to_px(bump.x + dx, bump.y + dy), 3
            )

    def body(
        self,
        to_px: ToPixel,
        pose: Sequence[float],
        length: float,
        width: float,
        colour: Any,
        line: int,
    ) -> None:
        """A chassis outline ``length`` × ``width`` [m] at ``pose`` with a nose line."""
        x, y, theta = float(pose[0]), float(pose[1]), float(pose[2])
        c, s = math.cos(theta), math.sin(theta)
        corners = [
            to_px(x + c * ax - s * ay, y + s * ax + c * ay)
            for ax, ay in (
                (0.5 * length, 0.5 * width),
                (0.5 * length, -0.5 * width),
                (-0.5 * length, -0.5 * width),
                (-0.5 * length, 0.5 * width),
            )
        ]
        pygame.draw.polygon(self.surface, colour, corners, line)
        nose = (x + c * 0.5 * length, y + s * 0.5 * length)
        pygame.draw.line(self.surface, (0, 0, 0), to_px(x, y), to_px(*nose), 2)

    def wheels(self, to_px: ToPixel, pose: Sequence[float], robot: RobotSpec) -> None:
        """The robot's wheels at its contacts (two, or four for a skid-steer robot): filled
        rectangles one wheel diameter long and a quarter of it wide, at ``pose``."""
        x, y, theta = float(pose[0]), float(pose[1]), float(pose[2])
        c, s = math.cos(theta), math.sin(theta)
        half_l = 0.5 * float(robot.wheel_diameter)
        half_w = 0.125 * float(robot.wheel_diameter)
        for _, cx, cy in robot.contacts():
            corners = [
                to_px(x + c * (cx + ax) - s * (cy + ay), y + s * (cx + ax) + c * (cy + ay))
                for ax, ay in (
                    (half_l, half_w),
                    (half_l, -half_w),
                    (-half_l, -half_w),
                    (-half_l, half_w),
                )
            ]
            pygame.draw.polygon(self.surface, WHEEL, corners, 0)

    def path(self, to_px: ToPixel, xy: NDArray[np.float64], colour: Any, line: int) -> None:
        """A polyline through the points ``xy`` (K, 2) [m] (nothing for fewer than two)."""
        if len(xy) > 1:
            pygame.draw.lines(self.surface, colour, False, [to_px(x, y) for x, y in xy], line)

    def close(self) -> None:
        if self.window is not None:
            pygame.display.quit()
        self.window = None


@dataclass
class _View:
    """The map: world bounds [m] fitted (equal scale on both axes) into a pixel rectangle."""

    left: int
    top: int
    width: int
    height: int
    x_min: float
    x_max: float
    y_min: float
    y_max: float

    @property
    def scale(self) -> float:
        """Pixels per metre."""
        return min(self.width / (self.x_max - self.x_min), self.height / (self.y_max - self.y_min))

    @property
    def span(self) -> float:
        """The larger side of the shown area [m]."""
        return max(self.width, self.height) / self.scale

    def world_bounds(self) -> tuple[float, float, float, float]:
        """What the pixel rectangle shows: x_min, x_max, y_min, y_max [m]."""
        cx, cy = 0.5 * (self.x_min + self.x_max), 0.5 * (self.y_min + self.y_max)
        hx, hy = 0.5 * self.width / self.scale, 0.5 * self.height / self.scale
        return cx - hx, cx + hx, cy - hy, cy + hy

    def to_pixel(self) -> ToPixel:
        scale = self.scale
        cx, cy = 0.5 * (self.x_min + self.x_max), 0.5 * (self.y_min + self.y_max)
        mx, my = self.left + 0.5 * self.width, self.top + 0.5 * self.height

        def px(x: float, y: float) -> Pixel:
            return int(mx + (x - cx) * scale), int(my - (y - cy) * scale)

        return px

    def include(self, xy: NDArray[np.float64], margin: float) -> None:
        """Grow the bounds (never shrink them: a video does not jump back) to hold ``xy``
        (K, 2) [m] with ``margin`` [m] to spare."""
        if len(xy) == 0:
            return
        low = xy.min(axis=0) - margin
        high = xy.max(axis=0) + margin
        self.x_min, self.y_min = min(self.x_min, low[0]), min(self.y_min, low[1])
        self.x_max, self.y_max = max(self.x_max, high[0]), max(self.y_max, high[1])


class TopDownRenderer:
    """Draws the floor, the route, the true and odometry paths and the robot (route envs)."""

    def __init__(self, robot: RobotSpec, floor: FloorSpec, mode: str, fps: float = 20.0) -> None:
        self.robot = robot
        self.floor = floor
        self.mode = mode
        self.fps = fps
        self.canvas = _Canvas(mode, fps, SIZE, SIZE, "odomgym")

    def _transform(self, route: Route) -> tuple[float, float, float]:
        points = [p for s in route.segments for p in (s.start, s.end)]
        xs = [p[0] for p in points] + [0.0]
        ys = [p[1] for p in points] + [0.0]
        margin = 0.1 * max(max(xs) - min(xs), max(ys) - min(ys), 1.0) + self.robot.chassis_length
        span = max(max(xs) - min(xs), max(ys) - min(ys)) + 2 * margin
        scale = SIZE / span
        cx, cy = 0.5 * (max(xs) + min(xs)), 0.5 * (max(ys) + min(ys))
        return scale, cx, cy

    def draw(
        self, route: Route, history: Sequence[tuple[float, float, float, float, float, float]]
    ) -> NDArray[np.uint8] | None:
        scale, cx, cy = self._transform(route)
        half = SIZE / scale / 2
        view = _View(0, 0, SIZE, SIZE, cx - half, cx + half, cy - half, cy + half)
        px = view.to_pixel()
        canvas = self.canvas
        canvas.surface.fill(BACKGROUND)
        canvas.grid(px, view)
        canvas.floor(px, self.floor)
        for segment in route.segments:
            if segment.kind == "drive":
                pygame.draw.line(canvas.surface, ROUTE, px(*segment.start), px(*segment.end), 1)
        if len(history) > 1:
            track = np.asarray(history, dtype=np.float64)
            canvas.path(px, track[:, 0:2], TRUE_PATH, 2)
            canvas.path(px, track[:, 3:5], ODOM_PATH, 2)
        last = history[-1] if history else (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        length, width = self.robot.chassis_length, self.robot.chassis_width
        canvas.body(px, last[3:6], length, width, ODOM_PATH, 1)
        canvas.body(px, last[0:3], length, width, TRUE_PATH, 3)
        canvas.wheels(px, last[0:3], self.robot)
        entries = [
            (TRUE_PATH, "true path (simulation)"),
            (ODOM_PATH, "odometry path"),
            (ROUTE, "planned route"),
        ]
        canvas.legend(entries, 10, 6, 200, 1)
        canvas.scale_bar(scale, 0, SIZE, SIZE)
        return canvas.present()

    @property
    def window(self) -> Any:
        """The pygame window of ``"human"`` mode (None for ``"rgb_array"``)."""
        return self.canvas.window

    def close(self) -> None:
        self.canvas.close()


# ---------------------------------------------------------------------------- two-truck vehicles


@dataclass
class VehicleTrace:
    """What a two-truck env keeps for drawing (only when it renders): per step the true,
    estimated and wheel-odometry poses of trucks A and B, (K, 2, 3) each [m, m, rad]."""

    true: list[NDArray[np.float64]]
    estimated: list[NDArray[np.float64]]
    odometry: list[NDArray[np.float64]]

    @classmethod
    def empty(cls) -> VehicleTrace:
        return cls([], [], [])

    def add(
        self,
        true: NDArray[np.float64],
        estimated: NDArray[np.float64],
        odometry: NDArray[np.float64],
    ) -> None:
        self.true.append(np.array(true, dtype=np.float64).reshape(2, 3))
        self.estimated.append(np.array(estimated, dtype=np.float64).reshape(2, 3))
        self.odometry.append(np.array(odometry, dtype=np.float64).reshape(2, 3))


class VehicleRenderer:
    """Draws a two-truck vehicle: the programmed path, cables, both trucks (true pose solid,
    estimated pose thin green), the linkage (or a trailer's tongue) with its current length, the
    true paths, the estimator's paths (IPEC's, or plain dead reckoning without it) and each
    truck's own wheel odometry. The view grows (never shrinks) to keep every path on screen.

    Args:
        trucks: the two trucks' specs (their chassis sizes are drawn).
        floor: the floor (cables laid during the run are passed to :meth:`draw`).
        paths: the programmed path's legs, (M, 2) points [m] each.
        estimator_label: the legend's name for the estimated poses.
        link_range: the linkage's end stops (l_min, l_max) [m], or None for a rigid tongue.
        names: the two trucks' short labels (drawn beside them) and legend names.
    """

    def __init__(
        self,
        trucks: tuple[RobotSpec, RobotSpec],
        floor: FloorSpec,
        paths: Sequence[NDArray[np.float64]],
        mode: str,
        fps: float,
        *,
        estimator_label: str,
        link_range: tuple[float, float] | None,
        names: tuple[tuple[str, str], tuple[str, str]] = (("A", "truck A"), ("B", "truck B")),
    ) -> None:
        self.trucks, self.floor, self.names = trucks, floor, names
        self.paths = [np.asarray(p, dtype=np.float64) for p in paths]
        self.estimator_label = estimator_label
        self.link_range = link_range
        every = np.concatenate(self.paths)
        low, high = every.min(axis=0), every.max(axis=0)
        wide = (high[0] - low[0]) > 2.5 * (high[1] - low[1])
        width, height = (800, 340) if wide else (640, 520)
        self.header = 66
        self.canvas = _Canvas(mode, fps, width, height, "odomgym: CLAPPER")
        self.margin = 0.08 * float(max(high - low)) + 1.0
        self.view = _View(
            0, self.header, width, height - self.header, low[0], high[0], low[1], high[1]
        )
        self.view.include(every, self.margin)

    def draw(
        self,
        trace: VehicleTrace,
        cables: Sequence[CableBump],
        status: str,
    ) -> NDArray[np.uint8] | None:
        """One frame of the run so far; ``status`` is the header's second line (time, leg)."""
        true = np.asarray(trace.true)
        estimated = np.asarray(trace.estimated)
        odometry = np.asarray(trace.odometry)
        view = self.view
        for poses in (true, estimated, odometry):
            if len(poses):
                view.include(poses[:, :, :2].reshape(-1, 2), 1.0)
        canvas = self.canvas
        px = view.to_pixel()
        surf = canvas.surface
        surf.fill(BACKGROUND)
        canvas.grid(px, view)
        canvas.floor(px, self.floor, cables)
        for points in self.paths:
            canvas.path(px, points, ROUTE, 2)
        # The truth wide underneath, the odometry over it and the estimate thin on top: an
        # estimate that stays on the truth shows as a green line inside the blue one.
        for k in (1, 0):  # truck A's lines on top of truck B's
            canvas.path(px, true[:, k, :2], TRUE_PATH, 4 if k == 0 else 3)
        for k in (1, 0):
            canvas.path(px, odometry[:, k, :2], ODOM_PATH if k == 0 else ODOM_PATH_B, 1)
        for k in (1, 0):
            canvas.path(px, estimated[:, k, :2], ESTIMATE, 1)
        if len(true):
            self._vehicle(px, true[-1], estimated[-1])
        self._header(status, true[-1] if len(true) else None)
        canvas.scale_bar(view.scale, 0, canvas.height, canvas.width)
        return canvas.present()

    def _vehicle(
        self, px: ToPixel, true: NDArray[np.float64], estimated: NDArray[np.float64]
    ) -> None:
        canvas = self.canvas
        a, b = true[0], true[1]
        length = float(math.hypot(a[0] - b[0], a[1] - b[1]))
        at_stop = self.link_range is not None and not (
            self.link_range[0] + 0.01 < length < self.link_range[1] - 0.01
        )
        for k, spec in enumerate(self.trucks):
            size = (spec.chassis_length, spec.chassis_width)
            canvas.body(px, estimated[k], *size, ESTIMATE, 1)
            canvas.body(px, true[k], *size, TRUE_PATH, 3)
        colour = LINK_AT_STOP if at_stop else LINK
        pygame.draw.line(canvas.surface, colour, px(*a[:2]), px(*b[:2]), 4)
        for k, spec in enumerate(self.trucks):
            # The label just beyond the chassis on its left-hand side (clear of both bodies).
            x, y, theta = (float(v) for v in true[k])
            reach = 0.5 * math.hypot(spec.chassis_length, spec.chassis_width) + 0.15
            cx, cy = px(x - reach * math.sin(theta), y + reach * math.cos(theta))
            label = self.names[k][0]
            image = canvas.big_font.render(label, True, TEXT)
            canvas.surface.blit(image, (cx - image.get_width() // 2, cy - image.get_height() // 2))

    def _header(self, status: str, true: NDArray[np.float64] | None) -> None:
        canvas = self.canvas
        pygame.draw.rect(canvas.surface, HEADER, pygame.Rect(0, 0, canvas.width, self.header))
        pygame.draw.line(
            canvas.surface, GRID, (0, self.header - 1), (canvas.width, self.header - 1)
        )
        entries = [
            (TRUE_PATH, "true paths"),
            (ESTIMATE, self.estimator_label),
            (ODOM_PATH, f"{self.names[0][1]} odometry"),
            (ODOM_PATH_B, f"{self.names[1][1]} odometry"),
            (ROUTE, "programmed path"),
            (BUMP, "cables"),
        ]
        canvas.legend(entries, 10, 6, canvas.width - 20, 3)
        line = status
        if true is not None:
            length = float(math.hypot(*(true[0, :2] - true[1, :2])))
            if self.link_range is None:
                line += f"   tongue (rigid) {length:.3f} m"
            else:
                low, high = self.link_range
                line += f"   linkage l = {length:.3f} m (stops {low:g}-{high:g} m)"
        canvas.text(line, (10, 46))

    @property
    def window(self) -> Any:
        return self.canvas.window

    def close(self) -> None:
        self.canvas.close()


# ---------------------------------------------------------------------------- self-calibration


@dataclass(frozen=True)
class SessionRun:
    """One run of a self-calibration session as drawn: the menu item's name, and its true and
    odometry paths (K, 2) [m] in the run's start frame (the robot starts at the origin heading
    +x), the odometry as the robot computed it with the corrections it drove with."""

    item: str
    true_xy: NDArray[np.float64]
    odometry_xy: NDArray[np.float64]
    finished: bool = True


@dataclass(frozen=True)
class SessionState:
    """The numbers the panel shows: floor, budget, runs used, estimated and (hidden from the
    agent) true E_d, E_b, E_s, and, at the end, the validated improvement."""

    floor: str
    budget: int
    runs_used: int
    estimated: tuple[float, float, float]
    true: tuple[float, float, float]
    last_item: str
    improvement: float | None = None


class SessionRenderer:
    """Draws a self-calibration session: every run so far overlaid in its start frame (the
    latest bold, older ones faded; blue truth, orange odometry, grey the nominal route shapes),
    and a panel with the experiment just chosen, the runs in order, the estimates of E_d, E_b,
    E_s beside the hidden truth, and the budget left as a bar."""

    WIDTH, HEIGHT, MAP = 860, 520, 520

    def __init__(self, mode: str, fps: float) -> None:
        self.canvas = _Canvas(mode, fps, self.WIDTH, self.HEIGHT, "odomgym: SelfCalibration")
        self.header = 48
        # Every menu item fits: 4 m squares either way (cw toward −y), 4 m straight runs.
        self.view = _View(0, self.header, self.MAP, self.HEIGHT - self.header, -1.0, 5.0, -5.0, 5.0)

    def draw(
        self,
        runs: Sequence[SessionRun],
        state: SessionState,
        routes: Sequence[NDArray[np.float64]],
    ) -> NDArray[np.uint8] | None:
        canvas, view = self.canvas, self.view
        for run in runs:
            view.include(run.true_xy, 0.4)
        px = view.to_pixel()
        surf = canvas.surface
        surf.fill(BACKGROUND)
        canvas.grid(px, view)
        for route in routes:
            canvas.path(px, route, ROUTE, 1)
        for k, run in enumerate(runs):
            latest = k == len(runs) - 1
            canvas.path(
                px, run.odometry_xy, ODOM_PATH if latest else FADED_ODOM, 3 if latest else 1
            )
            canvas.path(px, run.true_xy, TRUE_PATH if latest else FADED_TRUE, 3 if latest else 1)
            if latest and len(run.true_xy):
                end = px(*run.true_xy[-1])
                pygame.draw.circle(surf, TRUE_PATH, end, 5)
        start = px(0.0, 0.0)
        pygame.draw.circle(surf, TEXT, start, 4, 2)
        pygame.draw.rect(surf, HEADER, pygame.Rect(0, 0, self.MAP, self.header))
        pygame.draw.line(surf, GRID, (0, self.header - 1), (self.MAP, self.header - 1))
        entries = [
            (TRUE_PATH, "true path (latest run)"),
            (ODOM_PATH, "odometry path"),
            (FADED_TRUE, "earlier runs (true)"),
            (FADED_ODOM, "earlier runs (odometry)"),
        ]
        canvas.legend(entries, 10, 6, self.MAP - 20, 2)
        canvas.scale_bar(view.scale, 0, self.HEIGHT, self.MAP)
        self._panel(runs, state)
        return canvas.present()

    def _panel(self, runs: Sequence[SessionRun], state: SessionState) -> None:
        canvas = self.canvas
        panel = pygame.Rect(self.MAP, 0, self.WIDTH - self.MAP, self.HEIGHT)
        pygame.draw.rect(canvas.surface, HEADER, panel)
        pygame.draw.line(canvas.surface, GRID, panel.topleft, panel.bottomleft)
        left, y = self.MAP + 16, 12
        canvas.text(f"self-calibration, floor '{state.floor}'", (left, y), big=True)
        y += 30
        canvas.text("experiment chosen:", (left, y))
        canvas.text(state.last_item, (left + 124, y - 3), colour=TRUE_PATH, big=True)
        y += 26
        left_runs = state.budget - state.runs_used
        canvas.text(
            f"budget: {state.runs_used} of {state.budget} runs used, {left_runs} left", (left, y)
        )
        y += 18
        bar = pygame.Rect(left, y, self.WIDTH - self.MAP - 32, 10)
        pygame.draw.rect(canvas.surface, GRID, bar)
        used = round(bar.width * state.runs_used / max(state.budget, 1))
        pygame.draw.rect(
            canvas.surface, TRUE_PATH, pygame.Rect(bar.left, bar.top, used, bar.height)
        )
        y += 24
        canvas.text("estimate      truth (hidden)", (left + 40, y))
        y += 18
        for name, est, true in zip(("E_d", "E_b", "E_s"), state.estimated, state.true, strict=True):
            canvas.text(name, (left, y))
            canvas.text(f"{est:.4f}", (left + 40, y), colour=ESTIMATE)
            canvas.text(f"{true:.4f}", (left + 130, y))
            y += 18
        if state.improvement is not None:
            y += 4
            canvas.text(
                f"validated: E_max,syst {state.improvement:.1f}x better", (left, y), big=True
            )
            y += 24
        y += 8
        canvas.text("runs so far:", (left, y))
        y += 18
        rows = (self.HEIGHT - y - 10) // 16
        shown = list(enumerate(runs, 1))
        if len(shown) > rows:
            shown = shown[-(rows - 1) :]
            canvas.text("...", (left, y))
            y += 16
        for number, run in shown:
            mark = "" if run.finished else "  (did not finish)"
            canvas.text(f"{number:2d}. {run.item}{mark}", (left, y))
            y += 16

    @property
    def window(self) -> Any:
        return self.canvas.window

    def close(self) -> None:
        self.canvas.close()
