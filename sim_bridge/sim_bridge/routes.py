"""Where agents go: each agent's closed route, a rectangle in road (Frenet) coordinates."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Loops:
    """Each agent's closed route: a rectangle in Frenet space (s_a..s_b, d_a..d_b), walked from (s_a, d_a)."""

    s_a: np.ndarray
    s_b: np.ndarray
    d_a: np.ndarray
    d_b: np.ndarray

    def perimeter(self) -> np.ndarray:
        """Loop length in Frenet units."""
        return 2 * (self.s_b - self.s_a) + 2 * np.abs(self.d_b - self.d_a)

    def project(self, s: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Loop parameters (N, 4) of the nearest point on each of the four edges, and distances to them."""
        along, across = self.s_b - self.s_a, np.abs(self.d_b - self.d_a)
        sign = np.sign(self.d_b - self.d_a)
        t0 = np.clip(s - self.s_a, 0, along)
        t1 = np.clip((d - self.d_a) * sign, 0, across)
        t2 = np.clip(self.s_b - s, 0, along)
        t3 = np.clip((self.d_b - d) * sign, 0, across)
        u = np.stack([t0, along + t1, along + across + t2, 2 * along + across + t3], 1)
        distance = np.stack(
            [
                np.hypot(self.s_a + t0 - s, self.d_a - d),
                np.hypot(self.s_b - s, self.d_a + sign * t1 - d),
                np.hypot(self.s_b - t2 - s, self.d_b - d),
                np.hypot(self.s_a - s, self.d_b - sign * t3 - d),
            ],
            1,
        )
        return u, distance

    def frenet(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Frenet point at loop parameter u."""
        along, across = self.s_b - self.s_a, np.abs(self.d_b - self.d_a)
        u = np.mod(u, self.perimeter())
        sign = np.sign(self.d_b - self.d_a)
        s = np.select(
            [u < along, u < along + across, u < 2 * along + across],
            [self.s_a + u, self.s_b, self.s_b - (u - along - across)],
            self.s_a,
        )
        d = np.select(
            [u < along, u < along + across, u < 2 * along + across],
            [self.d_a, self.d_a + sign * (u - along), self.d_b],
            self.d_b - sign * (u - 2 * along - across),
        )
        return s, d
