"""The fused closed loop on a CUDA GPU: one thread per insect, a stretch of ticks per launch.

Each thread runs its insect's ticks as services.loop's fused loop runs them for all: sense, the
brain's tick (netlogo or phased), act (collisions, pushes, food, learning time, boundary), with no
host work between ticks. World and brain state stay on the device for the whole run; only the
metrics and the final state come back, into the same World and Brain objects the CPU path fills,
so the two paths are compared field by field (tests/test_gpu.py). The kernel is
services/gpu_kernels.py; docs/gpu.md says why it is a port of the CPU kernels and where a
device's floating point may differ.

numba.cuda is imported only when a run asks for the device. Without a GPU, under
NUMBA_ENABLE_CUDASIM=1, numba's CUDA simulator runs the same kernel in Python (slowly).
"""

from __future__ import annotations

import contextlib
import threading
import warnings
from collections.abc import Callable
from typing import Any

import numpy as np

from services.brain.brain import Brain, bind
from services.brain.build import TICK, TRAINING
from services.loop import check_loop, wiring
from services.world.world import BIN, RAY_STEP, VIEW, World

DEVICES = ("cuda",)
STRETCH = 1000  # ticks per kernel launch: long enough that a launch's cost is nothing beside it
THREADS = 128  # threads (insects) per block
LAUNCH = threading.Lock()  # one launch at a time: a launch only queues the kernel on its stream


def device_problem() -> str | None:
    """Why a run cannot go on a CUDA device here (one line), or None when it can."""
    try:
        from numba import cuda
    except ImportError as e:  # a numba without its CUDA target
        return f"numba's CUDA target cannot be imported ({e}); install the gpu extra: pip install 'spikinglab[gpu]'"
    if cuda.is_available():
        return None
    if getattr(cuda, "implementation", "") != "NVIDIA":  # numba's own CUDA target, without numba-cuda
        return "numba-cuda is not installed: pip install 'spikinglab[gpu]' on a machine with an NVIDIA GPU"
    return (
        "no CUDA GPU or driver found (numba.cuda.is_available() is False): run on a machine with an NVIDIA GPU "
        "and its driver"
    )


def simulated() -> bool:
    """Whether numba's CUDA simulator stands in for the device (NUMBA_ENABLE_CUDASIM=1)."""
    from numba.core import config

    return bool(config.ENABLE_CUDASIM)  # pyright: ignore[reportAttributeAccessIssue] (from the environment)


def check_device(device: str, cluster: str | None = None) -> None:
    """ValueError for a device this path does not know, or with a cluster; RuntimeError when it is
    missing here."""
    if device not in DEVICES:
        raise ValueError(f"device must be one of {', '.join(DEVICES)}, got {device!r}")
    if cluster is not None:
        raise ValueError("device and cluster: choose one (the cluster's workers run on their CPUs)")
    problem = device_problem()
    if problem is not None:
        raise RuntimeError(f"device={device!r} refused: {problem}, or use the CPU path (the default)")


def fused_loop_cuda(
    world: World,
    brain: Brain,
    ticks: int,
    stretch: int = STRETCH,
    on_noxious: Callable[[int, np.ndarray], object] | None = None,
) -> None:
    """`ticks` ticks of services.loop.fused_loop on the device: world and brain end as the CPU
    path leaves them (state, metrics, collision bins). Either semantics; an arena per insect.
    `on_noxious(k, rows)`: after each launch, its ticks from the call's tick k on, rows [n, A]
    uint8, 1 where an insect's pain sensor was fed (services.learning.noxious_ticks). The calls
    of several host threads run at once on the device: each has a stream of its own."""
    from numba import cuda

    from services.gpu_kernels import fused_kernel

    kernel: Any = fused_kernel  # a CUDA dispatcher: kernel[blocks, threads, stream](...)
    check_loop(world, brain, ticks)
    if world.shared:
        raise ValueError("fused_loop_cuda needs an arena per insect (in a shared one, insects race for food)")
    if brain.engine.order == "netlogo-stream":
        raise ValueError("order netlogo-stream runs on the CPU only: the device draws no NetLogo stream")
    t0, agents = world.tick, world.agents
    bins = np.zeros(((t0 + ticks) // BIN - t0 // BIN + 1, agents), np.int64)  # by bin from t0's
    bins[0] = world.bin_collisions
    host = _arguments(world, brain, bins)
    stream = cuda.stream()
    dev = [_each(x, lambda y: cuda.to_device(y, stream=stream)) for x in host]
    noxious = cuda.to_device(np.zeros((stretch if on_noxious else 0, agents), np.uint8), stream=stream)
    # numba's simulator runs a block's threads as Python threads that swap each device function's
    # module globals unlocked ("dictionary changed size during iteration", seen in a test run;
    # NVIDIA/numba-cuda#690): there, one thread a block, the blocks in turn. Same result.
    simulator = simulated()
    threads = 1 if simulator else min(THREADS, agents)
    tb0, blocks = int(brain.engine.state.clock[TICK]), (agents + threads - 1) // threads
    with _quiet_overflow() if simulator else contextlib.nullcontext():
        for done in range(0, ticks, stretch):
            n = min(stretch, ticks - done)
            with LAUNCH:  # numba-cuda's first launch loads the module, which two threads at once corrupt
                kernel[blocks, threads, stream](n, t0 + done, tb0 + done, t0 // BIN, *dev, noxious)
            if on_noxious is not None:
                rows = noxious[:n].copy_to_host(stream=stream)
                stream.synchronize()  # a copy on a stream may return before it is done
                on_noxious(done, rows)
    for d, x in zip(_flat(dev), _flat(host)):
        if x.flags.writeable:
            d.copy_to_host(x, stream=stream)
    stream.synchronize()
    _close_bins(world, bins, ticks)
    brain.engine.state.clock[TICK] += ticks
    bind(brain.engine.spiked, brain.actuator_neurons, brain.action_cols, brain.actions)


@contextlib.contextmanager
def _quiet_overflow():
    """The simulator's numpy scalars warn where the order's uint64 hash wraps, by design. (Not on a
    device: warnings' filters are global, and table1's threads would race to set them back.)"""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", "overflow encountered", RuntimeWarning)
        yield


def _close_bins(world: World, bins: np.ndarray, ticks: int) -> None:
    """Move the world's clock on as the CPU loop does, bin by bin, with the device's counts."""
    end, bin0 = world.tick + ticks, world.tick // BIN
    while world.tick < end:
        world.bin_collisions[:] = bins[world.tick // BIN - bin0]
        world.advance(min(end - world.tick, BIN - world.tick % BIN))  # closes the bin at its end


def _arguments(world: World, brain: Brain, bins: np.ndarray) -> list:
    """The kernel's arguments after its four numbers: arrays and named tuples of arrays. Read-only
    ones are not copied back."""
    from services.gpu_kernels import DeviceBrain, DeviceNet, DeviceWorld  # numba.cuda: only for a device run

    net, st = brain.engine.network, brain.engine.state
    netlogo = brain.engine.semantics == "netlogo"
    ray_steps = int(round(world.fpar[VIEW] / world.fpar[RAY_STEP]))
    world_cols, actuators = wiring(brain)  # as services.loop.fused_loop binds them
    flags = np.array([ray_steps, world.training, st.clock[TRAINING], net.rules, netlogo], np.int64)
    senses, drives = np.stack([brain.sensor_cols, brain.input_cols]), np.stack([actuators, world_cols])
    arrays = world.kernel_arrays() | {"bin": bins}  # the device counts bins by tick
    arrays.update({name: _read_only(arrays[name]) for name in ("arena_of", "fpar", "kind", "steps")})
    order = np.zeros(st.v.shape, np.uint64)  # each insect's netlogo order, scratch
    return [
        *(_read_only(x) for x in (flags, senses, drives)),
        DeviceWorld(**arrays),
        world.sensors,
        brain.feed,
        DeviceNet(*(_read_only(getattr(net, name)) for name in DeviceNet._fields)),
        DeviceBrain._make([*(getattr(st, name) for name in DeviceBrain._fields[:-1]), order]),
    ]


def _each(x: Any, f):
    """f of an array, or of each array of a named tuple (a named tuple of the results)."""
    return x._make(f(y) for y in x) if hasattr(x, "_make") else f(x)


def _flat(xs: list) -> list:
    return [y for x in xs for y in (x if isinstance(x, tuple) else (x,))]


def _read_only(x: np.ndarray) -> np.ndarray:
    view = x.view()
    view.flags.writeable = False
    return view
