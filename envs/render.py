"""Top-down rendering of a route env with pygame (the ``render`` extra).

Imported only when an env renders, so pygame stays optional.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from odomgym.floor import FloorSpec
from odomgym.robot import RobotSpec
from odomgym.routes import Route

try:
    import pygame
except ImportError as exc:  # pragma: no cover - depends on the environment
    raise ImportError("rendering needs pygame: pip install 'odomgym[render]'") from exc

__all__ = ["TopDownRenderer"]

SIZE = 600
BACKGROUND = (245, 245, 240)
GRID = (225, 225, 220)
ROUTE = (170, 170, 170)
TRUE_PATH = (31, 119, 180)
ODOM_PATH = (255, 127, 14)
BUMP = (90, 60, 40)
PATCH = (200, 225, 240)


class TopDownRenderer:
    """Draws the floor, the route, the true and odometry paths and the robot."""

    def __init__(self, robot: RobotSpec, floor: FloorSpec, mode: str, fps: float = 20.0) -> None:
        self.robot = robot
        self.floor = floor
        self.mode = mode
        self.fps = fps
        pygame.font.init()
        self.font = pygame.font.Font(None, 18)
        if mode == "human":
            pygame.display.init()
            self.window: Any = pygame.display.set_mode((SIZE, SIZE))
            pygame.display.set_caption("odomgym")
        else:
            self.window = None
        self.surface = pygame.Surface((SIZE, SIZE))
        self.clock = pygame.time.Clock()

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

        def px(x: float, y: float) -> tuple[int, int]:
            return int(SIZE / 2 + (x - cx) * scale), int(SIZE / 2 - (y - cy) * scale)

        surf = self.surface
        surf.fill(BACKGROUND)
        step = 1.0 if SIZE / scale < 20 else 5.0
        half = SIZE / scale / 2
        for k in range(int(-half // step) - 1, int(half // step) + 2):
            gx = round(cx / step) * step + k * step
            gy = round(cy / step) * step + k * step
            pygame.draw.line(surf, GRID, px(gx, cy - half), px(gx, cy + half))
            pygame.draw.line(surf, GRID, px(cx - half, gy), px(cx + half, gy))
        for patch in self.floor.patches:
            left, top = px(patch.x_min, patch.y_max)
            right, bottom = px(patch.x_max, patch.y_min)
            pygame.draw.rect(surf, PATCH, pygame.Rect(left, top, right - left, bottom - top))
        for bump in self.floor.bumps:
            dx, dy = (
                0.5 * bump.length * math.cos(bump.angle),
                0.5 * bump.length * math.sin(bump.angle),
            )
            pygame.draw.line(
                surf, BUMP, px(bump.x - dx, bump.y - dy), px(bump.x + dx, bump.y + dy), 3
            )
        for segment in route.segments:
            if segment.kind == "drive":
                pygame.draw.line(surf, ROUTE, px(*segment.start), px(*segment.end), 1)
        if len(history) > 1:
            pygame.draw.lines(surf, TRUE_PATH, False, [px(h[0], h[1]) for h in history], 2)
            pygame.draw.lines(surf, ODOM_PATH, False, [px(h[3], h[4]) for h in history], 2)
        last = history[-1] if history else (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        self._robot(surf, px, last[3], last[4], last[5], ODOM_PATH, 1)
        self._robot(surf, px, last[0], last[1], last[2], TRUE_PATH, 3)
        self._legend(surf)
        self._scale_bar(surf, scale)
        if self.mode == "human":
            assert self.window is not None
            self.window.blit(surf, (0, 0))
            pygame.event.pump()
            pygame.display.flip()
            self.clock.tick(self.fps)
            return None
        return np.transpose(np.array(pygame.surfarray.pixels3d(surf)), (1, 0, 2)).copy()

    def _legend(self, surf: Any) -> None:
        """Top-left key: which line is which."""
        entries = [
            (TRUE_PATH, "true path (simulation)"),
            (ODOM_PATH, "odometry path"),
            (ROUTE, "planned route"),
        ]
        for row, (colour, text) in enumerate(entries):
            y = 12 + 18 * row
            pygame.draw.line(surf, colour, (10, y), (34, y), 3)
            surf.blit(self.font.render(text, True, (40, 40, 40)), (40, y - 7))

    def _scale_bar(self, surf: Any, scale: float) -> None:
        """Bottom-left bar of a round length (1, 2 or 5 × 10^k m) about a sixth of the view."""
        target = SIZE / 6 / scale
        power = 10.0 ** math.floor(math.log10(target))
        length = max(m * power for m in (1.0, 2.0, 5.0) if m * power <= target)
        pixels = round(length * scale)
        y = SIZE - 20
        pygame.draw.line(surf, (40, 40, 40), (10, y), (10 + pixels, y), 3)
        for x in (10, 10 + pixels):
            pygame.draw.line(surf, (40, 40, 40), (x, y - 5), (x, y + 5), 2)
        label = f"{length:g} m" if length >= 1.0 else f"{length * 100:g} cm"
        surf.blit(self.font.render(label, True, (40, 40, 40)), (14 + pixels, y - 8))

    def _robot(
        self, surf: Any, px: Any, x: float, y: float, theta: float, colour: Any, width: int
    ) -> None:
        length, width_m = self.robot.chassis_length, self.robot.chassis_width
        c, s = math.cos(theta), math.sin(theta)
        corners = [
            (x + c * ax - s * ay, y + s * ax + c * ay)
            for ax, ay in (
                (0.5 * length, 0.5 * width_m),
                (0.5 * length, -0.5 * width_m),
                (-0.5 * length, -0.5 * width_m),
                (-0.5 * length, 0.5 * width_m),
            )
        ]
        pygame.draw.polygon(surf, colour, [px(*p) for p in corners], width)
        nose = (x + c * 0.5 * length, y + s * 0.5 * length)
        pygame.draw.line(surf, (0, 0, 0), px(x, y), px(*nose), 2)

    def close(self) -> None:
        if self.window is not None:
            pygame.display.quit()
        self.window = None
