"""The free-running brain's clock: its lateness statistics take the same memory after any number
of ticks, and their quantiles are those of every tick's lateness, within a bin. Its kernels are
compiled before it joins the bus."""

import subprocess
import sys
import textwrap

import numpy as np
import pytest

from services.brain.free_running import Clock, Lateness

from ..processes import ROOT

# a robot's first reading and the ticks after it, as the free-running brain steps them, counting the
# kernels that numba compiles for them (or loads from its cache: compiled there on an empty one)
FIRST_READING = textwrap.dedent(
    """
    import sys
    import numpy as np
    from numba.core.dispatcher import Dispatcher
    from services.brain.circuit import load_circuit
    from services.brain.node import BrainNode
    from services.bus.schemas import Array, Sensors, decode, encode
    from services.vocabulary import INSECT_SENSORS

    added = []
    compile_once = Dispatcher.compile

    def counted(dispatcher, signature):
        before = len(dispatcher.overloads)
        entry = compile_once(dispatcher, signature)
        added.extend([dispatcher.py_func.__name__] * (len(dispatcher.overloads) - before))
        return entry

    node = BrainNode(load_circuit("insect"), free_running=True, semantics="netlogo", order="random", seed=None)
    if sys.argv[1] == "compiled":
        node.compile_kernels()
    Dispatcher.compile = counted
    values = Array.of(np.full((1, len(INSECT_SENSORS)), 3.0))
    reading = decode(encode(Sensors(tick=0, names=INSECT_SENSORS, values=values, run="r")))
    node.start(reading)
    node.running.step(reading.values.numpy("values", "<f8", 2))  # a reading: a read-only view of the message
    node.running.step(np.full((1, len(INSECT_SENSORS)), np.nan))  # none fresh
    print(" ".join(added))
    """
)


def test_the_kernels_compiled_before_the_bus_are_all_that_a_robots_ticks_call():
    """On an empty kernel cache a compile holds the interpreter most of a minute: subscribed to a
    robot's readings, the brain's session lapsed meanwhile (docs/robot.md)."""
    compiles = {}
    for case in ("compiled", "not compiled"):
        done = subprocess.run(
            [sys.executable, "-c", FIRST_READING, case], cwd=ROOT, capture_output=True, text=True, timeout=300
        )
        assert done.returncode == 0, done.stderr
        compiles[case] = done.stdout.split()
    assert compiles["compiled"] == [] and compiles["not compiled"], compiles  # the control: the same ticks compile


def test_lateness_quantiles_are_those_of_all_ticks_within_half_a_percent():
    rng = np.random.default_rng(1)
    late = np.concatenate([rng.lognormal(np.log(20e-6), 0.5, 50_000), rng.uniform(1e-3, 5e-3, 600)])
    lateness = Lateness()
    for seconds in late:
        lateness.add(float(seconds))
    for q in (0.5, 0.99):
        assert lateness.quantile(q) == pytest.approx(np.quantile(late, q), rel=0.006), q
    assert lateness.max == late.max()
    stats = lateness.stats_ms()
    assert set(stats) == {"late_ms_median", "late_ms_p99", "late_ms_max"}
    assert stats["late_ms_max"] == round(late.max() * 1000, 3)


def test_on_time_ticks_and_no_ticks():
    lateness = Lateness()
    assert lateness.stats_ms() == {"late_ms_median": 0.0, "late_ms_p99": 0.0, "late_ms_max": 0.0}
    for _ in range(99):
        lateness.add(0.0)
    lateness.add(30.0)  # beyond the last bin: counted there, the maximum exact
    assert lateness.quantile(0.5) == 0.0 and lateness.max == 30.0 and lateness.quantile(1.0) == 30.0


def test_the_clock_keeps_the_same_memory_however_many_ticks():
    """At 1 kHz a robot brain ticks 3.6 million times an hour: nothing kept may grow with them."""
    clock = Clock(1e6)  # a tick due every microsecond: the clock never sleeps
    clock.wait()
    sizes = {name: sys.getsizeof(value) for name, value in vars(clock.lateness).items()}
    for _ in range(100_000):
        clock.wait()
    assert clock.lateness.total == 100_001
    assert {name: sys.getsizeof(value) for name, value in vars(clock.lateness).items()} == sizes
    assert all(not isinstance(value, list) for value in vars(clock).values())
