"""The insect's world (the NetLogo demo's): a patch arena with walls, predators and food.

A agents are stepped together; each has its own copy of the arena (independent seeds) or all
share one. The world is a grid of 1 x 1 patches, as in NetLogo: vision samples the patches along
a ray every 0.2 patch, touch is the patch under the insect. Sensing and acting are numba kernels
over all agents (docs/world.md says why this, and not per-agent pymunk queries, is the hot path;
services/world/physics.py holds the same map in a pymunk space).

One tick: sense() [vision, touch: reads only] -> the brain -> act(actions) [what the touch does:
collision, push, food; then actuators -> boundary check].
Nothing here knows Zenoh.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np
from numba import get_num_threads, njit, prange
from numba.core import types
from numba.experimental import structref

from services.kernels import Kernel
from services.params import PARALLEL_FROM, agent_columns, is_int, is_number
from services.snapshots import copy_into
from services.vocabulary import (
    BLACK,
    EMPTY,
    EV_ATE,
    EV_COLLISION,
    EV_LEARNED,
    EV_RESET,
    EVENT_COLUMNS,
    GREEN,
    INSECT_ACTIONS,
    INSECT_SENSORS,
    RED,
)

# Sensor columns the world publishes and action columns it takes (the bus's names; the circuit
# binds them by name).
SENSORS, ACTIONS = INSECT_SENSORS, INSECT_ACTIONS
PAIN, REWARD = SENSORS.index("pain"), SENSORS.index("reward")
BIN = 1000  # ticks per bin of the collision counts (metrics.bins)
COLOURS = GREEN + 1  # patch colours are 0..GREEN: the length of a table by colour
# patches: a step between two ticks longer than this is no move but a put-back at the start (a
# tick moves an insect move_step + push at most, 1.5 patches with the paper's steps): paths drawn
# are cut there
JUMP = 2.0
ROTATE, MOVE = ACTIONS.index("rotate"), ACTIONS.index("move")
# by colour: the sensor column of the smell that sees it (EMPTY: none)
_SMELLS = {BLACK: "smell_black", RED: "smell_red", GREEN: "smell_green"}
SMELL = tuple(SENSORS.index(_SMELLS[c]) if c in _SMELLS else -1 for c in range(COLOURS))
_NO_CHANGES = np.zeros((0, 4), np.int64)
_NO_CHANGES.flags.writeable = False


def world_actions(names, actions: np.ndarray) -> np.ndarray:
    """Actions given per name ([A, len(names)]) in the world's ACTIONS order; other names are ignored."""
    if tuple(names) == ACTIONS:
        return actions
    out = np.zeros((actions.shape[0], len(ACTIONS)), np.uint8)
    for k, name in enumerate(names):
        if name in ACTIONS:
            out[:, ACTIONS.index(name)] = actions[:, k]
    return out


@dataclass(frozen=True)
class WorldParams:
    """Every number of the world, with the model's defaults (NetLogo demo, patch units)."""

    x_min: int = 80
    x_max: int = 120
    y_min: int = 1
    y_max: int = 60
    wall_columns: tuple[int, ...] = (88, 94, 100, 106, 112, 118)
    wall_from_y: int = 4  # inner wall columns run from here to the top border
    red_fraction: float = 0.1
    green_fraction: float = 0.1
    start: tuple[float, float] = (102.0, 30.0)
    start_heading: float | None = None  # degrees; None: drawn from the seed per agent
    view_distance: float = 4.0
    ray_step: float = 0.2
    rotation_step: float = 5.0  # degrees per ROTATE spike (NetLogo demo: 4)
    move_step: float = 1.0  # patches per MOVE spike (NetLogo demo: 0.4)
    push: float = 0.5  # forward push on a noxious patch in training
    pain_value: float = 1.0  # value fed to the nociceptor on a noxious patch (NetLogo: 1)
    reward_value: float = 1.0  # value fed to the reward input on food (NetLogo: 1)
    noxious: tuple[int, ...] = (BLACK, RED)
    rewarding: tuple[int, ...] = (GREEN,)
    learned_after: int = 5000  # W: collision-free ticks that count as "learned"

    def __post_init__(self):
        """ValueError naming a value the world cannot take (the kernels trust every one)."""
        problems = [f"{name} {why}" for name, why in self._problems()]
        if problems:
            raise ValueError("world parameters: " + "; ".join(problems))

    def _problems(self):
        """(field, what is wrong with its value) for each value the world cannot take."""

        def number(x, low=-math.inf, above=False):
            return is_number(x) and (x > low if above else x >= low)

        def whole(x, low=-math.inf):
            return number(x, low) and x == int(x)

        def checked(names, ok, what):
            return ((k, f"{what}, got {getattr(self, k)!r}") for k in names if not ok(getattr(self, k)))

        wholes = ("x_min", "x_max", "y_min", "y_max", "wall_from_y")
        yield from checked(wholes, whole, "must be a whole number")
        yield from checked(("wall_columns",), lambda xs: all(whole(x) for x in xs), "must be whole numbers")
        if all(whole(getattr(self, k)) for k in wholes) and (self.width < 3 or self.height < 3):
            yield (
                "x_min .. x_max, y_min .. y_max",
                f"must span 3 patches each way or more, got {self.width} x {self.height}",
            )
        fractions = (self.red_fraction, self.green_fraction)
        if not all(number(f, 0) for f in fractions) or sum(fractions) > 1:
            yield "red_fraction, green_fraction", f"must be in [0, 1] and add up to 1 or less, got {fractions}"
        x, y = (self.x_min, self.x_max), (self.y_min, self.y_max)
        yield from checked(
            ("start",),
            lambda s: (
                isinstance(s, tuple | list)
                and len(s) == 2
                and all(number(c) for c in s)
                and x[0] <= s[0] <= x[1]
                and y[0] <= s[1] <= y[1]
            ),
            f"must be (x, y) within x {x[0]}..{x[1]}, y {y[0]}..{y[1]}",
        )
        yield from checked(("start_heading",), lambda h: h is None or number(h), "must be a number of degrees or None")
        above_0 = ("view_distance", "ray_step", "rotation_step", "move_step")
        yield from checked(above_0, lambda v: number(v, 0, above=True), "must be a number above 0")
        yield from checked(("push", "pain_value", "reward_value"), lambda v: number(v, 0), "must be a number >= 0")
        colours = lambda cs: all(whole(c, 0) and c < COLOURS for c in cs)  # noqa: E731
        yield from checked(("noxious", "rewarding"), colours, f"must be patch colours 0..{COLOURS - 1}")
        yield from checked(("learned_after",), lambda v: whole(v, 1), "must be a whole number of ticks >= 1")

    @property
    def start_x(self) -> float:
        return self.start[0]

    @property
    def start_y(self) -> float:
        return self.start[1]

    @property
    def width(self) -> int:
        return self.x_max - self.x_min + 1

    @property
    def height(self) -> int:
        return self.y_max - self.y_min + 1


# fpar columns: the WorldParams the kernels read, in this order
# (the rotation and move steps are per agent: World.steps)
WORLD_COLUMNS = (
    "x_min",
    "y_min",
    "view_distance",
    "ray_step",
    "push",
    "start_x",
    "start_y",
    "learned_after",
    "pain_value",
    "reward_value",
)
X_MIN, Y_MIN, VIEW, RAY_STEP, PUSH, START_X, START_Y, LEARNED_AFTER, PAIN_VALUE, REWARD_VALUE = range(
    len(WORLD_COLUMNS)
)

# The paper's steps are the default: with the NetLogo demo's smaller steps the insect creeps up to
# walls and does not learn avoidance in 40,000 ticks (docs/world.md).
PRESETS = {
    "paper": {},
    "netlogo": {"rotation_step": 4.0, "move_step": 0.4},
}


def params_for(preset: str = "paper", **overrides) -> WorldParams:
    """The world's parameters of a preset, some overridden; ValueError naming an unknown one."""
    if preset not in PRESETS:
        raise ValueError(f"unknown world preset {preset!r} (known: {', '.join(PRESETS)})")
    unknown = sorted(set(overrides) - {f.name for f in dataclasses.fields(WorldParams)})
    if unknown:
        raise ValueError(f"unknown world parameter(s) {', '.join(unknown)} (WorldParams has no such field)")
    return dataclasses.replace(WorldParams(), **{**PRESETS[preset], **overrides})


def generate_map(params: WorldParams, seed: int) -> np.ndarray:
    """A seeded arena: border and inner wall columns black, 10 % red, 10 % green inside."""
    p = params
    grid = np.zeros((p.width, p.height), dtype=np.uint8)
    grid[0, :] = grid[-1, :] = grid[:, 0] = grid[:, -1] = BLACK
    for x in p.wall_columns:
        if p.x_min < x < p.x_max:
            grid[x - p.x_min, p.wall_from_y - p.y_min :] = BLACK
    rng = np.random.default_rng(seed)
    u = rng.random((p.width - 2, p.height - 2))
    inner = grid[1:-1, 1:-1]  # red and green may overwrite inner wall cells
    inner[u < p.red_fraction] = RED
    inner[(u >= p.red_fraction) & (u < p.red_fraction + p.green_fraction)] = GREEN
    sx, sy = _patch(p.start[0], p.x_min), _patch(p.start[1], p.y_min)
    grid[sx, sy] = EMPTY  # the start patch is cleared
    return grid


def _patch(coord: float, origin: int) -> int:
    return int(math.floor(coord + 0.5)) - origin  # NetLogo: the patch whose centre is nearest


MAP_CHARS = {"#": BLACK, "R": RED, "G": GREEN, ".": EMPTY}


class MapError(ValueError):
    """A map file is wrong; the message names the file, the line and the problem."""


def load_map(path) -> tuple[np.ndarray, tuple[float, float]]:
    """A text map: one line per row, top row first; # wall, R predator, G food, . empty, S start.

    The arena's lower-left patch is (0, 0) in the map's own coordinates; returns the grid
    [x, y] and the start position.
    """
    try:
        with open(path, encoding="utf-8") as f:
            lines = f.read().splitlines()
    except OSError as e:
        raise MapError(f"{path}: cannot read map file: {e.strerror or e}") from None
    except UnicodeDecodeError as e:
        raise MapError(f"{path}: not a text map (not UTF-8: byte {e.start})") from None
    # (line number, row): blank lines and ; comments are not rows, but count as lines
    numbered = [(n, ln) for n, ln in enumerate(lines, 1) if ln.strip() and not ln.lstrip().startswith(";")]
    if not numbered:
        raise MapError(f"{path}: empty map")
    rows = [row for _, row in numbered]
    width = len(rows[0])
    start = None
    grid = np.zeros((width, len(rows)), dtype=np.uint8)
    for r, (line_no, row) in enumerate(numbered):
        if len(row) != width:
            raise MapError(f"{path}: line {line_no}: row has {len(row)} cells, the first row has {width}")
        y = len(rows) - 1 - r
        for x, ch in enumerate(row):
            if ch == "S":
                if start is not None:
                    raise MapError(f"{path}: line {line_no}: a second start 'S' (one only)")
                start = (float(x), float(y))
            elif ch in MAP_CHARS:
                grid[x, y] = MAP_CHARS[ch]
            else:
                raise MapError(
                    f"{path}: line {line_no}, column {x + 1}: unknown cell {ch!r} "
                    f"(use # wall, R predator, G food, . empty, S start)"
                )
    if start is None:
        raise MapError(f"{path}: no start 'S' in the map")
    if width < 3 or len(rows) < 3:
        raise MapError(f"{path}: the map must be at least 3 x 3")
    return grid, start


def map_world(path, base: WorldParams | None = None) -> tuple[WorldParams, np.ndarray]:
    """Params and grid for a map file: the arena is the map, its lower-left patch is (0, 0)."""
    grid, start = load_map(path)
    params = dataclasses.replace(
        base or WorldParams(),
        x_min=0,
        y_min=0,
        x_max=grid.shape[0] - 1,
        y_max=grid.shape[1] - 1,
        start=start,
        wall_columns=(),
    )
    return params, grid


@dataclass
class Metrics:
    """Per-agent counters, updated every tick."""

    collisions: np.ndarray  # [A] collision events (entering a noxious patch)
    collisions_by_colour: np.ndarray  # [A, COLOURS]
    food: np.ndarray  # [A] food patches eaten
    distance: np.ndarray  # [A] patches travelled (moves and pushes)
    last_collision: np.ndarray  # [A] tick of the last collision event (-1: none yet)
    last_noxious: np.ndarray  # [A] last tick on a noxious patch (-1: none yet): NetLogo's error-free counter
    learned_at: np.ndarray  # [A] learning time: last noxious tick before W collision-free ticks (-1: not yet)
    resets: np.ndarray  # [A] times the insect left the arena and was put back at the start
    bins: list = field(default_factory=list)  # collisions per 1,000 ticks, [A] per finished bin


# The arrays the kernels read and write, by name: World's attributes of these names, its act()
# buffer and current bin, then its Metrics' arrays. On the CPU they cross into the kernels as one
# WorldStruct (numba structref, as the engine's Network and State): one argument, not twenty. It
# holds the arrays themselves, so they are filled in place, never rebound; the sensors are not in
# it: the world service swaps World.sensors for a spare array every tick.
OWN_ARRAYS = ("grid", "arena_of", "fpar", "kind", "steps", "pos", "heading", "last_patch", "events", "eaten")
METRIC_ARRAYS = tuple(f.name for f in dataclasses.fields(Metrics) if f.name != "bins")
KERNEL_ARRAYS = (*OWN_ARRAYS, "actions", "bin", *METRIC_ARRAYS)


@structref.register
class WorldType(types.StructRef):
    def preprocess_fields(self, fields):
        return tuple((name, types.unliteral(t)) for name, t in fields)


class WorldStruct(structref.StructRefProxy):
    """A World's KERNEL_ARRAYS as its kernels take them (the arrays, not copies)."""


# And the CPU kernels' scratch, never saved: sin_cos [A, 2] of each insect's heading, and that
# heading's bits [A] (int64). libm's sincos was a tenth of `evaluate`'s time; a heading changes in
# about 1.5 % of an insect's ticks, so they are computed again only then (_sin_cos).
SCRATCH = ("sin_cos", "sin_cos_of")
structref.define_proxy(WorldStruct, WorldType, [*KERNEL_ARRAYS, *SCRATCH])


@njit(cache=True)
def _world_struct(arrays):
    """Made in compiled code, from numba's cache: a proxy's own constructor compiles anew in every process."""
    return WorldStruct(*arrays)


def checked_arguments(p: WorldParams, agents, seed, shared, grid, training, numbers) -> np.ndarray:
    """World's arguments checked (ValueError naming a wrong one); the agents' numbers, int64 [A]."""
    for name, value, low in (("agents", agents, 1), ("seed", seed, 0)):
        if not is_int(value) or not low <= value < 2**62:
            raise ValueError(f"{name}: a whole number >= {low} (below 2**62), got {value!r}")
    if not isinstance(training, bool | np.bool_) or not isinstance(shared, bool | np.bool_):
        raise ValueError(f"training and shared: True or False, got {training!r} and {shared!r}")
    given = np.arange(agents) if numbers is None else np.asarray(numbers)
    whole = given.astype(np.int64)
    if given.shape != (agents,) or (whole < 0).any() or (whole != given).any():
        raise ValueError(f"numbers: one whole number >= 0 per agent ({agents}), got {np.ravel(given).tolist()[:8]}")
    if shared and numbers is not None:
        raise ValueError("numbers: agents of a shared arena are its agents 0..A-1")
    if grid is not None:
        if np.shape(grid) != (p.width, p.height):  # a list of lists too; a string, a number: shape ()
            raise ValueError(f"grid shape {np.shape(grid)} does not match the params' arena {(p.width, p.height)}")
        if not np.isin(grid, np.arange(COLOURS)).all():
            unknown = sorted(set(np.unique(grid).tolist()) - set(range(COLOURS)))
            raise ValueError(f"grid: patch colours are 0..{COLOURS - 1}, it holds {unknown}")
    return whole


class World:
    """A insects in their arenas. `sense()` then `act(actions)` per tick.

    Agent a is agent `numbers[a]` (default a) of the world of `seed`: its arena and its brain's
    netlogo order come from seed + numbers[a], its heading from (seed, numbers[a]), so a population
    can hold the same insect several times (one per parameter setting). `agent_params`: the world's per-agent columns
    (services.params: rotation and move steps), each a number or one value per agent."""

    def __init__(
        self,
        params: WorldParams | None = None,
        agents: int = 1,
        seed: int = 0,
        shared: bool = False,
        grid: np.ndarray | None = None,
        training: bool = True,
        numbers=None,
        agent_params=None,
    ):
        if params is not None and not isinstance(params, WorldParams):
            raise TypeError(f"params: a WorldParams, e.g. params_for('paper'), got {params!r}")
        self.params = p = params or WorldParams()
        self.numbers = checked_arguments(p, agents, seed, shared, grid, training, numbers)
        self.agents, self.seed, self.shared = agents, seed, shared
        columns = agent_columns(agents, agent_params, "world")
        # per agent: degrees per ROTATE spike, patches per MOVE spike
        self.steps = np.column_stack(
            [
                columns.get("rotation_step", np.full(agents, p.rotation_step)),
                columns.get("move_step", np.full(agents, p.move_step)),
            ]
        )
        self.training = training
        self._custom_grid = grid
        n_arenas = 1 if shared else agents
        self.grid = np.zeros((n_arenas, p.width, p.height), dtype=np.uint8)
        self.pos = np.zeros((agents, 2))
        self.heading = np.zeros(agents)  # degrees, NetLogo convention: 0 = north, clockwise
        self.sensors = np.full((agents, len(SENSORS)), np.nan)
        self.last_patch = np.zeros(agents, dtype=np.int64)
        self.arena_of = np.zeros(agents, dtype=np.int64) if shared else np.arange(agents)
        self.fpar = np.array([getattr(p, name) for name in WORLD_COLUMNS], dtype=np.float64)
        # large populations: each kernel a loop across agents on every core (numba's threads); the
        # same result, as agents are independent (but for food in a shared arena: first come)
        large = self.world_kernels_parallel = agents >= PARALLEL_FROM
        # a parallel kernel's blocks (one a thread) come as an argument: numba cannot cache a kernel
        # that reads get_num_threads() itself, and compiled it anew in every process
        blocks = (get_num_threads(),)
        self._sense, self._sense_blocks = (Kernel(_sense_parallel), blocks) if large else (Kernel(sense_kernel), ())
        touch_parallel = large and not shared
        self._touch, self._touch_blocks = (
            (Kernel(_touch_parallel), blocks) if touch_parallel else (Kernel(touch_kernel), ())
        )
        self._act, self._act_blocks = (Kernel(_act_parallel), blocks) if large else (Kernel(act_kernel), ())
        self._actions = np.zeros((agents, len(ACTIONS)), np.uint8)  # act()'s, in the type its kernel was compiled for
        self.kind = np.zeros(COLOURS, dtype=np.uint8)  # per colour: 1 noxious, 2 rewarding
        for c in p.noxious:
            self.kind[c] = 1
        for c in p.rewarding:
            self.kind[c] = 2
        self.reset()

    def reset(self) -> None:
        """Fresh arenas and insects from the seed (agent a's arena: seed + a's; its heading: (seed, a)'s)."""
        p = self.params
        for g in range(self.grid.shape[0]):
            self.grid[g] = (
                self._custom_grid
                if self._custom_grid is not None
                else generate_map(p, self.seed + int(self.numbers[g]))
            )
        self.pos[:] = p.start
        if p.start_heading is not None:
            self.heading[:] = p.start_heading
        else:
            self.heading[:] = [np.random.default_rng((self.seed, int(k), 1)).uniform(0, 360) for k in self.numbers]
        self.tick = 0
        self.last_patch[:] = -1
        A = self.agents
        self.metrics = Metrics(
            collisions=np.zeros(A, np.int64),
            collisions_by_colour=np.zeros((A, COLOURS), np.int64),
            food=np.zeros(A, np.int64),
            distance=np.zeros(A),
            last_collision=np.full(A, -1, np.int64),
            last_noxious=np.full(A, -1, np.int64),
            learned_at=np.full(A, -1, np.int64),
            resets=np.zeros(A, np.int64),
        )
        self._bin = np.zeros(A, np.int64)
        self.events = np.zeros((A, len(EVENT_COLUMNS)), np.int64)  # this tick's events
        self.eaten = np.full((A, 2), -1, np.int64)  # this tick: grid index of the food eaten, or -1
        scratch = (np.zeros((A, 2)), np.full(A, -1, np.int64))  # bits -1: a NaN, no heading of a world
        self.struct = _world_struct((*self.kernel_arrays().values(), *scratch))  # the kernels' argument

    def sense(self) -> np.ndarray:
        """Vision then touch for tick self.tick: the sensors [A, len(SENSORS)] (NaN: nothing).

        Reads the world and changes nothing in it; what touching a patch does comes in act()."""
        self._sense(self.struct, self.sensors, *self._sense_blocks)
        return self.sensors

    def changes(self) -> np.ndarray:
        """The patches that changed in this tick's act(): rows (arena, x index, y index, colour)."""
        who = np.flatnonzero(self.eaten[:, 0] >= 0)
        if len(who) == 0:  # most ticks (the recorded loop asks every tick)
            return _NO_CHANGES
        return np.column_stack([self.arena_of[who], self.eaten[who], np.full(len(who), EMPTY)]).astype(np.int64)

    def act(self, actions: np.ndarray) -> None:
        """End tick self.tick: the patch touched (collision, push, food, learning time), then the
        actions [A, len(ACTIONS)] (nonzero: that actuator spiked), then the boundary check."""
        if actions.shape != self._actions.shape:
            raise ValueError(f"actions of shape {actions.shape}, expected {self._actions.shape} (agents, actions)")
        self._actions[:] = actions
        self._touch(self.struct, self.training, self.tick, *self._touch_blocks)
        self._act(self.struct, *self._act_blocks)
        self.advance(1)

    def kernel_arrays(self) -> dict[str, np.ndarray]:
        """The arrays the kernels take (KERNEL_ARRAYS, in that order): what self.struct holds."""
        own = {name: getattr(self, name) for name in OWN_ARRAYS}
        return own | {"actions": self._actions, "bin": self._bin} | {n: getattr(self.metrics, n) for n in METRIC_ARRAYS}

    @property
    def bin_collisions(self) -> np.ndarray:
        """[A]: collisions so far in the current bin of BIN ticks (the kernels add to it in place)."""
        return self._bin

    def advance(self, ticks: int) -> None:
        """The clock moved on by `ticks` ticks whose kernels ran (act(), or services.loop's fused
        loop, which stops at a bin's end): a bin that ends there is closed."""
        self.tick += ticks
        if self.tick % BIN == 0:
            self.metrics.bins.append(self._bin.copy())
            self._bin[:] = 0

    def snapshot(self) -> dict[str, np.ndarray]:
        """Copies of everything the next ticks depend on or report: arenas, poses, counters and
        the collision bins (whole-run checkpoints, services/snapshots.py)."""
        arrays = {name: array.copy() for name, array in self._state_arrays().items()}
        arrays["tick"] = np.array(self.tick, np.int64)
        arrays["bins"] = np.array(self.metrics.bins, np.int64).reshape(-1, self.agents)
        return arrays

    def restore(self, arrays: dict[str, np.ndarray]) -> None:
        """Back to a snapshot() of a world of the same arenas and agents, copied in place."""
        arrays = dict(arrays)
        tick, bins = int(arrays.pop("tick")), arrays.pop("bins")
        if bins.shape != (tick // BIN, self.agents):
            raise ValueError(f"world snapshot: {bins.shape[0]} bins of collisions at tick {tick}")
        copy_into(self._state_arrays(), arrays, "world snapshot")
        self.tick, self.metrics.bins = tick, list(bins)

    def _state_arrays(self) -> dict[str, np.ndarray]:
        m = self.metrics
        return {
            "grid": self.grid,
            "pos": self.pos,
            "heading": self.heading,
            "last_patch": self.last_patch,
            "bin": self._bin,
            **{f"metrics.{f.name}": getattr(m, f.name) for f in dataclasses.fields(m) if f.name != "bins"},
        }

    def patch_at(self, agent: int = 0) -> int:
        p = self.params
        x, y = _patch(self.pos[agent, 0], p.x_min), _patch(self.pos[agent, 1], p.y_min)
        if 0 <= x < p.width and 0 <= y < p.height:
            return int(self.grid[self.arena_of[agent], x, y])
        return EMPTY


@njit(cache=True, inline="always")
def _cell(x, y, x_min, y_min, width, height):
    """The patch at (x, y): its column and row in the grid, or (-1, -1) outside it. Numbers only:
    numba counts references to arrays handed to a helper at each call, even an inlined one."""
    ix = int(math.floor(x + 0.5)) - int(x_min)
    iy = int(math.floor(y + 0.5)) - int(y_min)
    if ix < 0 or iy < 0 or ix >= width or iy >= height:
        return -1, -1
    return ix, iy


@njit(cache=True, inline="always")
def _sin_cos(h, h_bits, kept_bits, kept_sin, kept_cos):
    """sin and cos of a heading h (degrees), and whether they are new: those kept when they are of
    the same bits (-0.0 is not 0.0). Numbers only, as _cell; the caller keeps new ones."""
    if h_bits == kept_bits:
        return kept_sin, kept_cos, False
    r = math.radians(h)
    return math.sin(r), math.cos(r), True


@njit(cache=True, inline="always")
def sense_range(lo, hi, w, sensors):
    """Vision then touch into `sensors` for agents lo..hi-1 of a WorldStruct `w`. The loop over
    agents is here, not in a caller: numba counts references to the arrays handed to an inlined
    function at every call, which in a loop over agents cost more than the sensing."""
    grid, arena_of, pos, heading, fpar, kind = w.grid, w.arena_of, w.pos, w.heading, w.fpar, w.kind
    sin_cos, of, bits = w.sin_cos, w.sin_cos_of, heading.view(np.int64)
    ray_steps = int(round(fpar[VIEW] / fpar[RAY_STEP]))
    x_min, y_min, width, height = fpar[X_MIN], fpar[Y_MIN], grid.shape[1], grid.shape[2]
    for a in range(lo, hi):
        g = arena_of[a]
        for k in range(sensors.shape[1]):
            sensors[a, k] = np.nan
        dx, dy, new = _sin_cos(heading[a], bits[a], of[a], sin_cos[a, 0], sin_cos[a, 1])
        if new:
            sin_cos[a, 0], sin_cos[a, 1], of[a] = dx, dy, bits[a]
        # vision: the first non-empty patch along the heading, sampled every ray_step. The
        # distance is a running sum, as NetLogo's `set itemcount itemcount + 0.2`: its 10th
        # sample is 1.9999999999999998, so a patch seen there fires its smell one tick sooner.
        d = 0.0
        for _step in range(ray_steps):
            d += fpar[RAY_STEP]
            ix, iy = _cell(pos[a, 0] + d * dx, pos[a, 1] + d * dy, x_min, y_min, width, height)
            colour = grid[g, ix, iy] if ix >= 0 else EMPTY
            if colour != EMPTY:
                sensors[a, SMELL[colour]] = d
                break
        # touch: the patch under the insect
        ix, iy = _cell(pos[a, 0], pos[a, 1], x_min, y_min, width, height)
        colour = grid[g, ix, iy] if ix >= 0 else EMPTY
        if kind[colour] == 1:
            sensors[a, PAIN] = fpar[PAIN_VALUE]
        elif kind[colour] == 2:
            sensors[a, REWARD] = fpar[REWARD_VALUE]


@njit(cache=True)
def sense_kernel(w, sensors):
    sense_range(0, w.pos.shape[0], w, sensors)


@njit(cache=True, parallel=True)
def _sense_parallel(w, sensors, blocks):
    agents = w.pos.shape[0]
    for c in prange(blocks):  # each agent reads the world and writes its own rows, in a shared arena too
        sense_range(c * agents // blocks, (c + 1) * agents // blocks, w, sensors)


@njit(cache=True, inline="always")
def touch_range(lo, hi, w, training, t):
    """What touching the patch under each insect lo..hi-1 does in tick t: count, push, eat, learn
    (the loop over agents here, as in sense_range)."""
    grid, arena_of, pos, heading, fpar, kind = w.grid, w.arena_of, w.pos, w.heading, w.fpar, w.kind
    last_patch, events, eaten, distance, bins = w.last_patch, w.events, w.eaten, w.distance, w.bin
    collisions, by_colour, food = w.collisions, w.collisions_by_colour, w.food
    last_collision, last_noxious, learned_at = w.last_collision, w.last_noxious, w.learned_at
    sin_cos, of, bits = w.sin_cos, w.sin_cos_of, heading.view(np.int64)
    x_min, y_min, width, height = fpar[X_MIN], fpar[Y_MIN], grid.shape[1], grid.shape[2]
    for a in range(lo, hi):
        g = arena_of[a]
        for k in range(events.shape[1]):
            events[a, k] = 0
        eaten[a, 0] = eaten[a, 1] = -1
        ix, iy = _cell(pos[a, 0], pos[a, 1], x_min, y_min, width, height)
        colour, patch = (grid[g, ix, iy], ix * height + iy) if ix >= 0 else (EMPTY, -1)
        if kind[colour] == 1:  # noxious
            last_noxious[a] = t
            if patch != last_patch[a]:  # entering it: a collision event
                collisions[a] += 1
                by_colour[a, colour] += 1
                bins[a] += 1
                last_collision[a] = t
                events[a, EV_COLLISION] = colour
            if training:  # pushed on, so it cannot spin on the spot forever
                sin_h, cos_h, new = _sin_cos(heading[a], bits[a], of[a], sin_cos[a, 0], sin_cos[a, 1])
                if new:
                    sin_cos[a, 0], sin_cos[a, 1], of[a] = sin_h, cos_h, bits[a]
                pos[a, 0] += fpar[PUSH] * sin_h
                pos[a, 1] += fpar[PUSH] * cos_h
                distance[a] += fpar[PUSH]
        elif kind[colour] == 2:  # rewarding: eaten (in a shared arena, by the first insect on it)
            grid[g, ix, iy] = EMPTY
            eaten[a, 0], eaten[a, 1] = ix, iy
            food[a] += 1
            events[a, EV_ATE] = 1
        last_patch[a] = patch
        # learning time: the last tick on a noxious patch before the first W ticks off them (NetLogo
        # resets its error_free_counter in every tick on one: staying on a wall is no progress)
        if learned_at[a] < 0 and t - max(last_noxious[a], 0) >= fpar[LEARNED_AFTER]:
            learned_at[a] = max(last_noxious[a], 0)
            events[a, EV_LEARNED] = 1


@njit(cache=True)
def touch_kernel(w, training, t):
    """What touching the patch under each insect does in tick t: count, push, eat, learn."""
    touch_range(0, w.pos.shape[0], w, training, t)


@njit(cache=True, parallel=True)
def _touch_parallel(w, training, t, blocks):
    """touch_kernel for agents each in an arena of its own (in a shared one, the first on a food patch eats it)."""
    agents = w.pos.shape[0]
    for c in prange(blocks):
        touch_range(c * agents // blocks, (c + 1) * agents // blocks, w, training, t)


@njit(cache=True, inline="always")
def act_range(lo, hi, w):
    """The actions (w.actions) of agents lo..hi-1, then the boundary check."""
    pos, heading, fpar, steps, actions = w.pos, w.heading, w.fpar, w.steps, w.actions
    events, distance, resets = w.events, w.distance, w.resets
    sin_cos, of, bits = w.sin_cos, w.sin_cos_of, heading.view(np.int64)
    width, height = w.grid.shape[1], w.grid.shape[2]
    for a in range(lo, hi):
        if actions[a, ROTATE]:
            heading[a] = (heading[a] + steps[a, 0]) % 360.0
        if actions[a, MOVE]:
            sin_h, cos_h, new = _sin_cos(heading[a], bits[a], of[a], sin_cos[a, 0], sin_cos[a, 1])
            if new:
                sin_cos[a, 0], sin_cos[a, 1], of[a] = sin_h, cos_h, bits[a]
            pos[a, 0] += steps[a, 1] * sin_h
            pos[a, 1] += steps[a, 1] * cos_h
            distance[a] += steps[a, 1]
        # boundary: leaving the arena (past the centre line of its border) puts the insect back
        # at its start, as NetLogo's check-boundaries does
        x = pos[a, 0] - fpar[X_MIN]
        y = pos[a, 1] - fpar[Y_MIN]
        if x < 0.0 or y < 0.0 or x > width - 1 or y > height - 1:
            pos[a, 0] = fpar[START_X]
            pos[a, 1] = fpar[START_Y]
            resets[a] += 1
            events[a, EV_RESET] = 1


@njit(cache=True)
def act_kernel(w):
    act_range(0, w.pos.shape[0], w)


@njit(cache=True, parallel=True)
def _act_parallel(w, blocks):
    agents = w.pos.shape[0]
    for c in prange(blocks):
        act_range(c * agents // blocks, (c + 1) * agents // blocks, w)
