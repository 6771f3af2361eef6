"""Bus messages -> a Rerun recording on a `tick` timeline, logged in batches (no zenoh here).

Each kind of data is buffered per tick and sent as columns (`send_columns`) every `flush_every`
ticks, never one log call per value. What goes where:

  /world/map                 the arena (SegmentationImage + AnnotationContext); again when food is eaten
  /world/insects             every agent's position, every tick
  /world/heading/agent<a>    heading arrow of a detail agent
  /world/vision/agent<a>     the vision ray of a detail agent, coloured by what it sees
  /world/trail/agent<a>      the path of the last `trail` ticks (every 50 ticks)
  /world/pain, /world/reward where a detail agent felt pain or found food
  /brain/agent<a>/spikes/<node>     spike raster: the node's row index at each tick it spiked
  /brain/agent<a>/potentials        membrane potentials of all neurons
  /brain/agent<a>/weights           plastic weights, every N ticks
  /learning/collisions_per_1000, /learning/food    the learning curve (mean over agents)
  /events                    text: start, world and brain on or off the bus, learning reached,
                             rejected messages, run ended
"""

from __future__ import annotations

from collections import defaultdict

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from services.bus.schemas import RUN_ID, BrainLayout, BrainState, BusError, WorldMap, WorldState
from services.vocabulary import BLACK, EMPTY, EV_LEARNED, GREEN, RED
from services.world.world import BIN, COLOURS, JUMP, WorldParams

from .shards import ShardJoin

PATCH_COLOURS = [
    (EMPTY, "floor", (24, 24, 28)),
    (BLACK, "wall", (215, 215, 215)),
    (RED, "predator", (220, 50, 47)),
    (GREEN, "food", (60, 190, 80)),
]
SEEN_COLOUR = {BLACK: (215, 215, 215), RED: (255, 80, 80), GREEN: (90, 230, 110)}
SMELLS = {"smell_black": BLACK, "smell_red": RED, "smell_green": GREEN}
TRAIL_EVERY, TRAIL_STEP = 50, 5  # ticks between trail updates; keep every 5th position
DEFAULT = WorldParams()  # the arena and the view of a run whose map has not come (yet)


def blueprint(detail: int = 0) -> rrb.Blueprint:
    """World view beside spike raster, potentials, weights and the learning curve."""
    recent = [
        rrb.VisibleTimeRange(
            "tick", start=rrb.TimeRangeBoundary.cursor_relative(seq=-300), end=rrb.TimeRangeBoundary.cursor_relative()
        )
    ]
    whole = [rrb.VisibleTimeRange("tick", start=rrb.TimeRangeBoundary.infinite(), end=rrb.TimeRangeBoundary.infinite())]
    # the whole run on the x axis, not linked to the raster's 300-tick window
    all_ticks = rrb.archetypes.TimeAxis(
        link=rrb.components.LinkAxis.Independent,
        view_range=rrb.components.TimeRange(
            start=rrb.TimeRangeBoundary.infinite(), end=rrb.TimeRangeBoundary.infinite()
        ),
    )
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(
                rrb.Spatial2DView(name="world", origin="/world"),
                rrb.TextLogView(name="events", origin="/events"),
                row_shares=[4, 1],
            ),
            rrb.Vertical(
                rrb.TimeSeriesView(name="spike raster", origin=f"/brain/agent{detail}/spikes", time_ranges=recent),
                rrb.TimeSeriesView(
                    name="membrane potentials", origin=f"/brain/agent{detail}/potentials", time_ranges=recent
                ),
                rrb.TimeSeriesView(
                    name="plastic weights", origin=f"/brain/agent{detail}/weights", time_ranges=whole, axis_x=all_ticks
                ),
                rrb.TimeSeriesView(name="learning", origin="/learning", time_ranges=whole, axis_x=all_ticks),
            ),
            column_shares=[1, 1],
        ),
        collapse_panels=True,
    )


class Recorder:
    """Turns decoded bus messages into Rerun data. `on(message)` per message, `close()` at the end."""

    def __init__(self, rec: rr.RecordingStream, detail=(0,), flush_every: int = 1000, trail: int = 2000):
        self.rec, self.detail, self.flush_every, self.trail = rec, tuple(detail), flush_every, trail
        self.first_tick: int | None = None
        self.last_tick = -1
        self.layout: BrainLayout | None = None
        self.run: str | None = None  # the run recorded
        self.first_map: WorldMap | None = None
        self.grid = None  # [arenas, width, height] as the world last told
        self.x_min = self.y_min = 0
        self.spike_counts: np.ndarray | None = None  # [agents, nodes] spikes seen (tests, summary)
        self.brain_shape: tuple | None = None  # (agents, nodes, neurons, synapses) of the first brain state
        self.agents = 0
        self._flushed_to = -1
        self._collisions_at_bin = None
        self.brain_done = False  # the brain's final batch has arrived
        self.world_done = False  # the world's final batch has arrived
        self._announced = False  # whether "recording starts at tick N" was said
        self._trail: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # agent -> (ticks, positions)
        self._last_pose = None  # (tick, pos [A, 2], heading [A]) after the last tick of the world's last batch
        self.missing: dict[str, int] = {}  # "world" / "brain" -> ticks of its state that never came
        self.next_tick: dict[str, int] = {}  # the tick each state stream's next batch should start at (once one came)
        self.shards = ShardJoin()  # a sharded world's slices, joined into the population's state and map
        self._reset_buffers()
        rec.log("/world/map", rr.AnnotationContext([(c, name, rgb) for c, name, rgb in PATCH_COLOURS]), static=True)
        rec.log(
            "/learning/collisions_per_1000",
            rr.SeriesLines(names="collision events per 1,000 ticks", colors=(220, 50, 47), widths=2),
            static=True,
        )
        rec.log("/learning/food", rr.SeriesLines(names="food eaten (mean)", colors=(60, 190, 80)), static=True)
        rec.log("/world/pain", rr.Points2D([], colors=[(255, 60, 60)]), static=True)

    def _reset_buffers(self) -> None:
        self.b = defaultdict(list)  # kind -> list of rows, flushed as columns

    # --- geometry: world patches -> image pixels (north up) -------------------------------------
    def view(self, xy: np.ndarray) -> np.ndarray:
        out = np.empty_like(xy, dtype=np.float64)
        out[..., 0] = xy[..., 0] - self.x_min + 0.5
        out[..., 1] = (self.height - 1) - (xy[..., 1] - self.y_min) + 0.5
        return out

    @property
    def height(self) -> int:
        return self.grid.shape[2] if self.grid is not None else DEFAULT.height

    # --- messages ---------------------------------------------------------------------------------
    def fits(self, message) -> None:
        """BusError unless `message` fits what this recording holds: the same agents and brain
        layout as the messages before it, map changes inside the map. A message that does not fit
        is refused whole, before anything of it is logged."""

        def refuse(why):
            raise BusError(f"does not fit the recording: {why}")

        self.fits_run(message)
        if isinstance(message, WorldState):
            agents, changes = message.pos.shape[1], message.changes.numpy("changes", "<i8", 2)
            if self.agents and agents != self.agents:
                refuse(f"{agents} agents, the world had {self.agents}")
            if len(changes) and self.grid is not None:
                limits = np.array([2**62, self.grid.shape[0], self.grid.shape[1], self.grid.shape[2], COLOURS])
                if ((changes < 0) | (changes >= limits)).any():
                    refuse("a map change outside the map")
        elif isinstance(message, BrainState):
            nodes, neurons, synapses = message.spiked.shape[2], message.potentials.shape[2], message.weights.shape[1]
            shape = (message.spiked.shape[1], nodes, neurons, synapses)
            if self.brain_shape is not None and shape != self.brain_shape:  # its batches are joined at a flush
                refuse(
                    "a brain state of {} agents, {} nodes, {} neurons, {} synapses; before {}, {}, {}, {}".format(
                        *shape, *self.brain_shape
                    )
                )
            if self.layout is not None and (nodes, neurons, synapses) != (
                len(self.layout.nodes),
                self.layout.neurons,
                len(self.layout.synapses),
            ):
                refuse(
                    f"{nodes} nodes, {neurons} neurons, {synapses} synapses; the brain's layout says "
                    f"{len(self.layout.nodes)}, {self.layout.neurons}, {len(self.layout.synapses)}"
                )
        elif isinstance(message, BrainLayout) and self.layout is not None and message != self.layout:
            refuse("a second brain layout, not the one the recording has")
        elif isinstance(message, BrainLayout) and self.brain_shape is not None:
            if (len(message.nodes), message.neurons, len(message.synapses)) != self.brain_shape[1:]:
                refuse(
                    "a layout of {} nodes, {} neurons, {} synapses for brain states of {}, {}, {}".format(
                        len(message.nodes), message.neurons, len(message.synapses), *self.brain_shape[1:]
                    )
                )
        elif isinstance(message, WorldMap) and self.agents and self.grid is not None:
            if message.grid.shape[1:] != self.grid.shape[1:]:
                refuse(f"a map of {list(message.grid.shape[1:])} patches during a run on {list(self.grid.shape[1:])}")
            if message != self.first_map:
                refuse("a second map during the run, not the one it began on")

    def fits_run(self, message) -> None:
        """BusError unless `message` is of the run recorded (or may start it)."""
        if self.run is None and not isinstance(message, (WorldMap, BrainLayout)) and not RUN_ID.fullmatch(message.run):
            raise BusError(
                f"does not fit the recording: a {type(message).__name__} of no run the services name, before "
                "the run's map or brain layout"
            )
        if self.run is not None and message.run != self.run:
            raise BusError(f"another run: {message.run!r}, the recording's is {self.run!r}")

    def on(self, message) -> None:
        if isinstance(message, (WorldMap, WorldState)) and message.population:  # a world shard's slice
            self.fits_run(message)
            joined = self.shards.take(message)  # the population's, once every shard's has come
            self.run = message.run
            for whole in joined:
                self.on(whole)
            return
        self.fits(message)
        if self.run is None:  # the run of the first map or layout: the services send those first
            self.run = message.run
        handler = {
            WorldMap: self.on_world_map,
            WorldState: self.on_world_state,
            BrainState: self.on_brain_state,
            BrainLayout: self.on_brain_layout,
        }[type(message)]
        if message.tick >= 0 and not isinstance(message, (BrainLayout, WorldMap)):
            # the earliest tick held; said once, at the first flush (a batch may start earlier than
            # the message that happened to come first)
            self.first_tick = message.tick if self.first_tick is None else min(self.first_tick, message.tick)
        handler(message)  # it moves last_tick on to its batch's last tick (a final batch may hold none)
        if self.last_tick - self._flushed_to >= self.flush_every:
            self.flush()

    def on_world_map(self, m: WorldMap) -> None:
        self.first_map = self.first_map or m
        self.grid = m.grid.numpy("grid", "|u1", 3).copy()
        self.x_min, self.y_min = m.x_min, m.y_min
        self._log_map(m.tick)

    @property
    def arena_shown(self) -> int:
        """The arena drawn: the first detail agent's (all agents share arena 0 when shared)."""
        return min(self.detail[0], self.grid.shape[0] - 1) if self.grid is not None else 0

    def _log_map(self, tick: int) -> None:
        if self.grid is None:
            return
        self.rec.set_time("tick", sequence=tick)
        self.rec.log("/world/map", rr.SegmentationImage(self.grid[self.arena_shown][:, ::-1].T.copy()))

    def on_world_state(self, m: WorldState) -> None:
        """A batch of consecutive ticks."""
        sensed = m.sensors.numpy("sensors", "<f8", 3)
        pos, heading = m.pos.numpy("pos", "<f8", 3), m.heading.numpy("heading", "<f8", 2)
        events, food = m.events.numpy("events", "<i8", 3), m.food.numpy("food", "<i8", 2)
        collisions = m.collisions.numpy("collisions", "<i8", 2)
        changes = m.changes.numpy("changes", "<i8", 2)
        self.agents = pos.shape[1]
        self._count_gap("world", m.tick, len(pos))
        self.last_tick = max(self.last_tick, m.tick + len(pos) - 1)
        ticks = m.tick + np.arange(len(pos))
        if len(ticks):  # none in a run's final batch when it ended before its first tick
            self.b["pose"].append((ticks, pos, heading))
            self._keep_vision(ticks, m.sensor_names, sensed, pos, heading)
        if self.grid is not None:
            for t in np.intersect1d(changes[:, 0], ticks):  # the patches eaten in these ticks, in tick order
                mine = changes[changes[:, 0] == t]
                for _, arena, ix, iy, colour in mine:
                    self.grid[arena, ix, iy] = colour
                if (mine[:, 1] == self.arena_shown).any():
                    self._log_map(int(t))
        for k in np.flatnonzero((ticks + 1) % BIN == 0):  # the learning curve, per BIN ticks like the world's
            # The collisions count from the run's start (a resumed run's too), so a bin's are known
            # from the count at its start: 0 for the run's first, else the end of the bin before,
            # which a recording begun later (a resumed run's part, a late recorder) has not seen.
            at_start = 0 if ticks[k] + 1 == BIN else self._collisions_at_bin
            if at_start is not None:
                self.b["bins"].append((int(ticks[k]), float((collisions[k] - at_start).mean()), float(food[k].mean())))
            self._collisions_at_bin = collisions[k].copy()
        for k, a in zip(*np.nonzero(events[:, :, EV_LEARNED])):
            t = int(ticks[k])
            self.event(f"agent {a} learned: no collision for the required run of ticks (tick {t})", "INFO", t)
        if m.final:
            self.world_done = True
            # at its last tick: the recording's ticks are those run (0 .. N - 1 of N)
            self.event(f"run ended at tick {m.tick + len(pos)}", "INFO", m.tick + len(pos) - 1)

    def _keep_vision(self, ticks, names, sensed, pos, heading) -> None:
        """Each detail agent's vision ray (from where it stood after the tick before, as far as the
        nearest smell, in its colour; the view distance and grey when it smells nothing) and whether
        it felt pain or reward, for the ticks of one world batch."""
        first_pos, first_heading = pos[0], heading[0]
        last = self._last_pose  # the ray of a batch's first tick starts at the last batch's last pose
        if last is not None and last[0] == ticks[0] - 1 and last[1].shape == pos.shape[1:]:
            first_pos, first_heading = last[1], last[2]
        before_pos = np.concatenate([first_pos[None], pos[:-1]])
        before_heading = np.concatenate([first_heading[None], heading[:-1]])
        self._last_pose = (int(ticks[-1]), pos[-1], heading[-1])
        smells = [j for j, name in enumerate(names) if name in SMELLS]
        palette = np.array([SEEN_COLOUR[SMELLS[names[j]]] for j in smells] + [(110, 110, 110)], np.uint8)
        every = np.arange(len(ticks))
        for a in (a for a in self.detail if a < self.agents):
            distances = np.where(np.isnan(sensed[:, a, smells]), np.inf, sensed[:, a, smells])  # [T, smells]
            nearest = distances.argmin(axis=1) if smells else np.zeros(len(ticks), np.int64)
            d = distances[every, nearest] if smells else np.full(len(ticks), np.inf)
            seen = np.isfinite(d)
            rad = np.radians(before_heading[:, a])
            tip = before_pos[:, a] + np.where(seen, d, DEFAULT.view_distance)[:, None] * np.stack(
                [np.sin(rad), np.cos(rad)], axis=1
            )
            felt = [
                ~np.isnan(sensed[:, a, names.index(n)]) if n in names else np.zeros(len(ticks), bool)
                for n in ("pain", "reward")
            ]
            self.b[f"vision{a}"].append(
                (ticks, np.stack([before_pos[:, a], tip], axis=1), palette[np.where(seen, nearest, len(smells))], *felt)
            )

    def on_brain_layout(self, m: BrainLayout) -> None:
        self.layout = m
        for a in self.detail:
            base = f"/brain/agent{a}"
            for k, name in enumerate(m.nodes):
                colour = (255, 200, 60) if k >= m.neurons else (120, 180, 255)
                self.rec.log(
                    f"{base}/spikes/{k:02d}_{name}",
                    rr.SeriesPoints(names=name, colors=colour, marker_sizes=2.0),
                    static=True,
                )
            self.rec.log(f"{base}/potentials", rr.SeriesLines(names=list(m.nodes[: m.neurons])), static=True)
            self.rec.log(f"{base}/weights", rr.SeriesLines(names=[m.synapses[k] for k in m.plastic]), static=True)

    def on_brain_state(self, m: BrainState) -> None:
        """A batch of consecutive ticks, and the weights after its last one."""
        spiked = m.spiked.numpy("spiked", "|u1", 3)
        potentials = m.potentials.numpy("potentials", "<f4", 3)
        agents = spiked.shape[1]
        rows = [a for a in self.detail if a < agents]
        if self.brain_shape is None:  # fits() holds every later one to it
            self.brain_shape = (*spiked.shape[1:], m.potentials.shape[2], m.weights.shape[1])
            self.spike_counts = np.zeros(spiked.shape[1:], np.int64)
        self.spike_counts += spiked.sum(axis=0, dtype=np.int64)
        self._count_gap("brain", m.tick, len(spiked))
        if len(spiked):  # the batch as arrays, [T, detail rows, nodes or neurons]: flush() joins them
            self.b["brain"].append((np.arange(m.tick, m.tick + len(spiked)), spiked[:, rows], potentials[:, rows]))
        last = m.tick + len(spiked) - 1
        self.last_tick = max(self.last_tick, last)
        weights = m.weights.numpy("weights", "<f8", 2)
        self.b["weights"].append((last, weights[rows]))
        self.brain_done = m.final

    def _count_gap(self, stream: str, first: int, ticks: int) -> None:
        """Count and say the ticks of a state stream that never came (dropped on the way)."""
        expected = self.next_tick.get(stream)
        if expected is not None and first > expected:
            self.missing[stream] = self.missing.get(stream, 0) + first - expected
            self.event(
                f"ticks {expected}..{first - 1} of the {stream}'s state are missing: dropped on the way (the "
                "recorder fell behind)",
                "WARN",
                first,
            )
        self.next_tick[stream] = max(expected or 0, first + ticks)

    def event(self, text: str, level: str = "INFO", tick: int | None = None) -> None:
        self.rec.set_time("tick", sequence=max(tick if tick is not None else self.last_tick, 0))
        self.rec.log("/events", rr.TextLog(text, level=level))

    # --- batches ----------------------------------------------------------------------------------
    def flush(self) -> None:
        """Send everything buffered as columns, one call per entity."""
        b, self.b = self.b, defaultdict(list)
        self._flushed_to = self.last_tick
        if not self._announced and self.first_tick is not None:
            self._announced = True
            begun = self.first_map.tick if self.first_map is not None else 0  # the world's map: where its data begin
            if self.first_tick > begun:
                self.event(
                    f"recording starts at tick {self.first_tick}: the recorder started late", "WARN", self.first_tick
                )
            elif begun > 0:  # the map of a run resumed from its checkpoint
                self.event(f"the run resumed at tick {begun}: this recording holds it from there", "INFO", begun)
        if b["pose"]:
            self._flush_world(b)
        if b["brain"] or b["weights"]:
            self._flush_brain(b["brain"], b["weights"])
        if b["bins"]:
            ticks = np.array([r[0] for r in b["bins"]])
            self._columns("/learning/collisions_per_1000", ticks, rr.Scalars.columns(scalars=[r[1] for r in b["bins"]]))
            self._columns("/learning/food", ticks, rr.Scalars.columns(scalars=[r[2] for r in b["bins"]]))
        self.rec.flush()

    def _columns(self, path: str, ticks, columns) -> None:
        self.rec.send_columns(path, indexes=[rr.TimeColumn("tick", sequence=np.asarray(ticks))], columns=columns)

    def _flush_world(self, b) -> None:
        ticks, pos, heading = (np.concatenate(column) for column in zip(*b["pose"]))  # [T], [T, A, 2], [T, A]
        T, A = pos.shape[:2]
        colours = np.tile(np.array([(255, 150, 40)] * A, np.uint8), (T, 1))
        sizes = np.full((T, A), 0.45, np.float32)
        for a in self.detail:
            if a < A:
                colours.reshape(T, A, 3)[:, a] = (255, 230, 0)
                sizes[:, a] = 0.7
        self._columns(
            "/world/insects",
            ticks,
            rr.Points2D.columns(
                positions=self.view(pos).reshape(-1, 2), colors=colours, radii=sizes.reshape(-1)
            ).partition([A] * T),
        )
        for a in (a for a in self.detail if a < A):
            self._flush_agent(a, ticks, pos[:, a], heading[:, a], b[f"vision{a}"])

    def _flush_agent(self, a, ticks, pos, heading, vision) -> None:
        self._flush_heading(a, ticks, pos, heading)
        if vision:
            self._flush_vision(a, vision)
        self._flush_trail(a, ticks, pos)

    def _flush_heading(self, a, ticks, pos, heading) -> None:
        rad = np.radians(heading)
        ahead = np.stack([np.sin(rad), np.cos(rad)], axis=1)
        start = self.view(pos)
        tip = self.view(pos + 1.2 * ahead)
        self._columns(
            f"/world/heading/agent{a}",
            ticks,
            rr.Arrows2D.columns(
                origins=start, vectors=tip - start, colors=np.tile([255, 230, 0], (len(ticks), 1))
            ).partition([1] * len(ticks)),
        )

    def _flush_vision(self, a, vision) -> None:
        # strips as one [T, 2, 2] array: Rerun converts it at once, a list strip by strip
        ray_ticks, rays, ray_colours, hurt, fed = (np.concatenate(column) for column in zip(*vision))
        rays = self.view(rays)
        self._columns(
            f"/world/vision/agent{a}",
            ray_ticks,
            rr.LineStrips2D.columns(
                strips=rays, colors=ray_colours, radii=np.full(len(rays), 0.08, np.float32)
            ).partition([1] * len(rays)),
        )
        for flags, path, colour in ((hurt, "/world/pain", (255, 60, 60)), (fed, "/world/reward", (90, 230, 110))):
            # a mark in the ticks it happens, an empty batch in the others (no stale mark)
            marks = rays[flags, 0]
            if len(marks) or path == "/world/pain":
                self._columns(
                    path,
                    ray_ticks,
                    rr.Points2D.columns(
                        positions=marks,
                        colors=np.tile(np.array(colour, np.uint8), (len(marks), 1)),
                        radii=np.full(len(marks), 0.9, np.float32),
                    ).partition(flags.astype(np.int64)),
                )

    def _flush_trail(self, a, ticks, pos) -> None:
        # the trail: every TRAIL_EVERY ticks, the last `trail` positions, split where it jumped (reset)
        old_ticks, old_pos = self._trail.get(a, (np.zeros(0, np.int64), np.zeros((0, 2))))
        history_ticks = np.concatenate([old_ticks, ticks])
        history = np.concatenate([old_pos, pos])
        self._trail[a] = (history_ticks[-self.trail :], history[-self.trail :])
        strips, counts, when = [], [], []
        shown = self.view(history)  # once for the whole history: the same points as piece by piece
        # jumps before each position, tick to tick: a line between two positions kept (every
        # TRAIL_STEP-th) is drawn only if no jump came between them
        jumps = np.concatenate([[0], np.cumsum(np.linalg.norm(np.diff(history, axis=0), axis=1) > JUMP)])
        for t in ticks[(ticks % TRAIL_EVERY) == 0]:
            end = np.searchsorted(history_ticks, t, side="right")  # the ticks come in order
            part = slice(max(0, end - self.trail), end, TRAIL_STEP)
            pieces = np.split(shown[part], np.flatnonzero(np.diff(jumps[part])) + 1)
            pieces = [p for p in pieces if len(p) > 1]
            strips += pieces
            counts.append(len(pieces))
            when.append(t)
        if when:
            self._columns(
                f"/world/trail/agent{a}",
                when,
                rr.LineStrips2D.columns(
                    strips=strips,
                    colors=np.tile([255, 230, 0, 120], (len(strips), 1)).astype(np.uint8),
                    radii=np.full(len(strips), 0.1, np.float32),
                ).partition(counts),
            )

    def _flush_brain(self, batches, weights) -> None:
        if batches:  # [T], [T, shown, nodes], [T, shown, neurons]
            ticks, spiked_rows, potential_rows = (np.concatenate(column) for column in zip(*batches))
        shown = spiked_rows.shape[1] if batches else len(weights[0][1])
        for i, a in enumerate(self.detail[:shown]):
            base = f"/brain/agent{a}"
            if batches:
                spiked = spiked_rows[:, i]  # [T, nodes]
                names = self.layout.nodes if self.layout else tuple(f"n{k}" for k in range(spiked.shape[1]))
                for k, name in enumerate(names):
                    when = ticks[spiked[:, k] > 0]
                    if len(when):  # the raster row: the node's row number, only in the ticks it spiked
                        self._columns(
                            f"{base}/spikes/{k:02d}_{name}",
                            when,
                            rr.Scalars.columns(scalars=np.full(len(when), len(names) - k, np.float64)),
                        )
                pot = potential_rows[:, i].astype(np.float64)
                self._columns(f"{base}/potentials", ticks, rr.Scalars.columns(scalars=pot))
            if weights and self.layout is not None:
                w = np.stack([x[1][i][list(self.layout.plastic)] for x in weights])
                self._columns(f"{base}/weights", [x[0] for x in weights], rr.Scalars.columns(scalars=w))

    def ticks_held(self) -> str:
        """The ticks recorded, for the log: "ticks 0..99999", or "no ticks"."""
        if self.first_tick is None or self.last_tick < self.first_tick:  # a final batch alone holds none
            return "no ticks"
        return f"ticks {self.first_tick}..{self.last_tick}"

    def close(self) -> None:
        self.flush()
