"""The world's map and insects in a pymunk space: continuous geometry beside the patch grid.

The grid (world.py) is the model: vision samples patches every 0.2 patch, as NetLogo does, for all
agents at once. This space holds the same map as static 1 x 1 boxes, one per non-empty patch
(their collision_type is the colour), and each insect as a small kinematic circle. It answers
what needs exact geometry: the first patch a ray really crosses and its exact distance (the
simulated EV3's ultrasonic sensor, and a cross-check of the grid's sampled vision in the tests).
"""

from __future__ import annotations

import math

import numpy as np
import pymunk

from services.vocabulary import EMPTY

from .world import World

INSECT_RADIUS = 0.3  # patches; the body is for display and contact, sensing uses its centre


def build_space(world: World, arena: int = 0) -> pymunk.Space:
    """A pymunk space of one arena of `world`: its non-empty patches and its insects."""
    space = pymunk.Space()
    add_boxes(space, world, arena, 1.0, world.grid[arena] != EMPTY)
    for a in np.flatnonzero(world.arena_of == arena):
        body = pymunk.Body(body_type=pymunk.Body.KINEMATIC)
        body.position = tuple(world.pos[a])
        body.angle = math.radians(90.0 - world.heading[a])  # pymunk: counter-clockwise from +x
        shape = pymunk.Circle(body, INSECT_RADIUS)
        shape.sensor = True
        shape.filter = pymunk.ShapeFilter(categories=0b10, mask=0)  # not seen by rays
        space.add(body, shape)
    return space


def build_objects(world: World, size: float, colours, arena: int = 0) -> pymunk.Space:
    """Square objects `size` patches wide in the centre of every patch of `colours` (the EV3
    floor's obstacles: what an ultrasonic sensor sees), collision_type their patch's colour."""
    space = pymunk.Space()
    add_boxes(space, world, arena, size, np.isin(world.grid[arena], colours))
    return space


def add_boxes(space: pymunk.Space, world: World, arena: int, size: float, where: np.ndarray) -> None:
    """A static box `size` patches wide centred on each patch `where` is true; collision_type its colour."""
    p, grid, h = world.params, world.grid[arena], size / 2
    for ix, iy in zip(*np.nonzero(where)):
        cx, cy = p.x_min + ix, p.y_min + iy
        box = pymunk.Poly(space.static_body, [(cx - h, cy - h), (cx + h, cy - h), (cx + h, cy + h), (cx - h, cy + h)])
        box.collision_type = int(grid[ix, iy])
        box.sensor = True  # patches are smelled and touched, never pushed against
        space.add(box)


def ray(space: pymunk.Space, start, heading_deg: float, distance: float, colours=None):
    """First patch box crossed by the ray (NetLogo heading), as (colour, exact distance), or (EMPTY, None).

    With `colours`, only boxes of those colours are considered (an ultrasonic sees obstacles only).
    """
    h = math.radians(heading_deg)
    x0, y0 = start
    end = (x0 + distance * math.sin(h), y0 + distance * math.cos(h))
    hits = space.segment_query((x0, y0), end, 0, pymunk.ShapeFilter(mask=0b1))
    best = None
    for hit in hits:
        if colours is not None and hit.shape.collision_type not in colours:
            continue
        if best is None or hit.alpha < best.alpha:
            best = hit
    if best is None:
        return EMPTY, None
    return best.shape.collision_type, best.alpha * distance
