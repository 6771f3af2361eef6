"""The pymunk space holds the same map: its exact rays agree with the grid's sampled vision."""

import math

import numpy as np
import pytest

from services.vocabulary import EMPTY
from services.world.physics import build_space, ray
from services.world.world import SENSORS, World

SMELLS = [SENSORS.index(s) for s in ("smell_black", "smell_red", "smell_green")]


def grid_vision(world, a=0):
    s = world.sense()[a]
    seen = [(colour, s[k]) for colour, k in zip((1, 2, 3), SMELLS) if not np.isnan(s[k])]
    return seen[0] if seen else (EMPTY, None)


def test_space_mirrors_the_map():
    w = World(seed=2)
    space = build_space(w)
    assert len(space.shapes) == np.count_nonzero(w.grid[0]) + 1  # patches and the insect
    colours = sorted(s.collision_type for s in space.shapes if s.body is space.static_body)
    assert colours == sorted(w.grid[0][w.grid[0] > 0].tolist())


def test_exact_rays_agree_with_sampled_vision():
    rng = np.random.default_rng(0)
    w = World(seed=4, training=False)
    space = build_space(w)
    step, view = w.params.ray_step, w.params.view_distance
    agree = diagonal = axis_checked = 0
    for k in range(400):
        axis_aligned = k % 2 == 0
        heading = float(rng.choice([0, 90, 180, 270])) if axis_aligned else float(rng.uniform(0, 360))
        x, y = rng.uniform(81, 119), rng.uniform(2, 59)
        if w.grid[0, int(math.floor(x + 0.5)) - 80, int(math.floor(y + 0.5)) - 1] != EMPTY:
            continue  # standing on a patch: touch, not vision
        w.pos[0], w.heading[0] = (x, y), heading
        colour, exact = ray(space, (x, y), heading, view + 1e-9)
        sampled_colour, sampled = grid_vision(w)
        if axis_aligned:
            # along an axis no patch can slip between samples: the first sample past the boundary
            axis_checked += 1
            first_sample = None if exact is None else math.ceil(exact / step - 1e-9) * step
            if first_sample is not None and first_sample <= view + 1e-9:
                assert sampled_colour == colour
                assert sampled == pytest.approx(first_sample)
            else:
                assert sampled_colour == EMPTY
        else:
            # diagonal rays can clip a patch corner between two samples: agreement, not identity
            diagonal += 1
            agree += sampled_colour == colour
    assert axis_checked > 100 and diagonal > 100
    assert agree >= 0.9 * diagonal
