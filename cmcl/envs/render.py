"""Offscreen pygame drawing of an mpe2 world inside its walls (rgb_array frames for GIFs).

Where it sits: used by the PettingZoo envs' `render()` (render_mode="rgb_array"); evaluation and the
demo turn the frames into GIFs. Draws like mpe2's renderer (filled discs with a black border, colour
x 200) but with a fixed camera on the arena and the wall square added. Needs no display: pygame is
imported lazily with SDL's dummy video driver.
"""

from __future__ import annotations

import os

import numpy as np

from cmcl.envs.common import ARENA_HALF

FRAME_SIZE = 400  # pixels, square
_MARGIN = 20  # pixels between the walls and the frame edge


def _pygame():
    """Import pygame headless (no window, no support banner)."""
    os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
    os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")
    import pygame

    return pygame


def draw_world(world, rings: tuple[float, ...] = (), size: int = FRAME_SIZE) -> np.ndarray:
    """uint8[size, size, 3] image of `world` (an mpe2 World): walls, landmarks/obstacles, agents.

    rings: optional radii drawn as thin grey circles around each landmark (e.g. the 0.1 cover radius).
    """
    pygame = _pygame()
    surface = pygame.Surface((size, size))
    surface.fill((255, 255, 255))
    scale = (size - 2 * _MARGIN) / (2 * ARENA_HALF)  # pixels per arena unit

    def to_px(p: np.ndarray) -> tuple[float, float]:
        return (size / 2 + p[0] * scale, size / 2 - p[1] * scale)  # y up, as mpe2

    wall = pygame.Rect(_MARGIN, _MARGIN, size - 2 * _MARGIN, size - 2 * _MARGIN)
    pygame.draw.rect(surface, (0, 0, 0), wall, 3)
    for lm in world.landmarks:
        for r in rings:
            pygame.draw.circle(surface, (190, 190, 190), to_px(lm.state.p_pos), r * scale, 1)
    for entity in list(world.landmarks) + list(world.agents):
        centre = to_px(entity.state.p_pos)
        radius = max(entity.size * scale, 1.0)
        colour = tuple(int(c) for c in np.clip(np.asarray(entity.color) * 200, 0, 255))
        pygame.draw.circle(surface, colour, centre, radius)
        pygame.draw.circle(surface, (0, 0, 0), centre, radius, 1)
    frame = np.array(pygame.surfarray.pixels3d(surface))  # [W, H, 3]
    return np.ascontiguousarray(frame.transpose(1, 0, 2))
