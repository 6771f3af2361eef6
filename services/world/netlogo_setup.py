"""The SpikingLab demo's `setup` replayed on NetLogo's random stream: its arena, patch by patch, and
the insect's first heading, for `random-seed N` (docs/netlogo-random.md).

Every draw of the source's setup after `random-seed` is made here in the source's order: the
shuffles of each `ask patches with [...]` of `draw-world`, its `random(10)` per inner patch, the
colour and heading of each new turtle, and the shuffles of `one-of <breed> with [...]`, which
the source calls to find neurons by label. Nothing else is modelled: positions, shapes and
links draw nothing.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from services.vocabulary import BLACK, EMPTY, GREEN, RED

from .netlogo_random import NetLogoRandom
from .world import WorldParams

# The demo's NetLogo world (its GRAPHICS-WINDOW): patches 0..120 x 0..60. `with` and `ask` see
# patches in NetLogo's order, rows from the top, each left to right.
WORLD_X, WORLD_Y = 120, 60
PATCHES = [(x, y) for y in range(WORLD_Y, -1, -1) for x in range(WORLD_X + 1)]
# the source's globals min_x_boundary .. max_y_boundary, which the arena must match
BOUNDARY = (80, 1, 120, 60)
CLEARED = (102, 46)  # setup paints this patch black (empty) after draw-world
WALL = "white"  # NetLogo's wall colour; red and green as here


@dataclass(frozen=True)
class NetLogoSetup:
    """What `setup` leaves: the arena (grid[x - 80, y - 1], this project's colours), the insect's
    heading (degrees, NetLogo's: 0 north, clockwise) and the stream, ready for the first tick."""

    grid: np.ndarray
    heading: float
    stream: NetLogoRandom


def spikinglab_setup(seed: int, params: WorldParams | None = None, legacy_long: bool = True) -> NetLogoSetup:
    """Run the source's setup from `random-seed seed` (NetLogo 6's nextLong unless told not to)."""
    p = params or WorldParams()
    if (p.x_min, p.y_min, p.x_max, p.y_max) != BOUNDARY:
        raise ValueError(
            f"the NetLogo arena is x 80..120, y 1..60; these params' is x {p.x_min}..{p.x_max}, y {p.y_min}..{p.y_max}"
        )
    rng = NetLogoRandom(legacy_long=legacy_long)
    rng.random_seed(seed)
    colours = draw_world(rng)
    colours[CLEARED] = "black"
    heading = build_insect(rng)
    return NetLogoSetup(arena_grid(colours, p), float(heading), rng)


def draw_world(rng: NetLogoRandom) -> dict[tuple[int, int], str]:
    """`draw-world`: the coloured patches (absent: black) after its seven kinds of ask."""
    x0, y0, x1, y1 = BOUNDARY
    colours: dict[tuple[int, int], str] = {}

    def ask_patches_with(test, paint) -> None:
        for patch in rng.ask_order([q for q in PATCHES if test(*q)]):
            paint(patch)

    def wall(patch) -> None:
        colours[patch] = WALL

    ask_patches_with(lambda x, y: x >= x0 and y == y0 and x <= x1, wall)
    ask_patches_with(lambda x, y: x >= x0 and y == y1, wall)
    ask_patches_with(lambda x, y: y >= y0 and x == x0 and x <= x1, wall)
    ask_patches_with(lambda x, y: y >= y0 and x == x1, wall)
    for columns in range(3, 22, 3):  # `while [ccolumns < 20] [set ccolumns ccolumns + 3 ...]`
        column = x0 + 2 + columns * 2  # the last, 124, lies outside the world: an empty ask
        ask_patches_with(lambda x, y, c=column: y0 + 3 <= y <= y1 + 15 and x == c, wall)

    def random_colour(patch) -> None:
        draw = rng.random(10)
        if draw == 1:
            colours[patch] = "red"
        elif draw == 2:
            colours[patch] = "green"

    ask_patches_with(lambda x, y: x0 < x < x1 and 1 < y < y1, random_colour)
    return colours


# The source's setup after draw-world, in order (the insect demo's build of its circuit):
# ("normal", label), ("input", label, target label), ("synapse", pre label, post label),
# ("feed", input label), ("creature", reward, pain, move, rotate labels), ("sensor", input label)
CIRCUIT_SETUP: tuple[tuple, ...] = (
    ("normal", 11), ("input", 1, 11), ("normal", 12), ("input", 2, 12), ("normal", 13), ("input", 3, 13),
    ("normal", 21), ("input", 4, 21), ("normal", 22), ("input", 5, 22),
    ("synapse", 11, 21), ("synapse", 11, 22), ("synapse", 12, 21),
    ("synapse", 12, 22), ("synapse", 13, 21), ("synapse", 13, 22),
    ("normal", 31), ("normal", 32),
    ("synapse", 21, 22), ("synapse", 22, 21), ("synapse", 21, 32), ("synapse", 22, 31),
    ("normal", 23), ("normal", 24), ("synapse", 23, 24), ("synapse", 24, 23), ("input", 6, 23),
    ("synapse", 23, 22),
    ("feed", 6),
    ("creature", 5, 4, 31, 32),
    ("sensor", 1), ("sensor", 2), ("sensor", 3),
)  # fmt: skip


class _Turtles:
    """Who numbers and the breeds (each in who order) of the turtles setup creates."""

    def __init__(self, rng: NetLogoRandom) -> None:
        self.rng = rng
        self.who = 0
        self.breeds: dict[str, list[tuple[int, int]]] = {}

    def create(self, breed: str, label: int = -1) -> tuple[int, int]:
        """`create-<breed> 1 [...]`: a colour and a heading drawn; returns (who, heading)."""
        _, heading = self.rng.turtle_colour_heading()
        who, self.who = self.who, self.who + 1
        self.breeds.setdefault(breed, []).append((who, label))
        return who, heading

    def one_with(self, breed: str, label: int | None = None, who: int | None = None) -> int:
        """`one-of <breed> with [label = ...]` (NetLogo's one-of-with): the breed in ask order,
        stopping at the first match; returns its who."""
        for found, found_label in self.rng.ask_order(self.breeds[breed]):
            if found_label == label or found == who:
                return found
        raise ValueError(f"no {breed} with label {label} / who {who}")


def build_insect(rng: NetLogoRandom) -> int:
    """The neuron types, the circuit, the insect, its sensors and sight line; returns the insect's
    heading (create-testcreatures draws it)."""
    turtles = _Turtles(rng)
    turtles.create("neurontypes")  # setup-neurontype 1 (set-...-learning-params asks one: no draw)
    turtles.create("neurontypes")  # setup-neurontype 2
    heading = None
    for step in CIRCUIT_SETUP:
        kind, *labels = step
        if kind == "normal":  # create, then set-neuron-to-neurontype asks single agents
            turtles.create("normalneurons", labels[0])
        elif kind == "input":  # the target by label, then create, then setup-input-synapse by who
            target = turtles.one_with("normalneurons", label=labels[1])
            turtles.create("inputneurons", labels[0])
            turtles.one_with("normalneurons", who=target)
        elif kind == "synapse":  # both ends by label; creating one link draws nothing
            turtles.one_with("normalneurons", label=labels[0])
            turtles.one_with("normalneurons", label=labels[1])
        elif kind == "feed":
            turtles.one_with("inputneurons", label=labels[0])
        elif kind == "creature":  # create-creature: reward, pain inputs; move, rotate neurons
            turtles.one_with("inputneurons", label=labels[0])
            turtles.one_with("inputneurons", label=labels[1])
            turtles.one_with("normalneurons", label=labels[2])
            turtles.one_with("normalneurons", label=labels[3])
            _, heading = turtles.create("testcreatures")
        elif kind == "sensor":
            turtles.one_with("inputneurons", label=labels[0])
            turtles.create("visualsensors")
    turtles.create("sightlines")  # create-sightline; attaching it asks single agents
    assert heading is not None
    return heading


def arena_grid(colours: dict[tuple[int, int], str], p: WorldParams) -> np.ndarray:
    """The arena's patches as this project's grid: NetLogo's white walls are BLACK here."""
    code = {WALL: BLACK, "red": RED, "green": GREEN, "black": EMPTY}
    grid = np.zeros((p.width, p.height), dtype=np.uint8)
    for (x, y), colour in colours.items():
        if p.x_min <= x <= p.x_max and p.y_min <= y <= p.y_max:
            grid[x - p.x_min, y - p.y_min] = code[colour]
    return grid
