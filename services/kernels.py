"""A numba kernel called once a tick, without numba's dispatcher after the first call. Importing this
module (as the engine and the world do) makes the process say when it compiles kernels, and cache
them by their place in services/ (services/kernel_locator.py)."""

from __future__ import annotations

from numba import typeof

from services import kernel_locator
from services.kernel_cache import say_when_compiling

say_when_compiling()  # the modules whose kernels compile for minutes import this one
kernel_locator.register()  # before they define them


class Kernel:
    """`kernel(*args)`, as numba's dispatcher runs it the first time; after that, straight into the
    function it compiled for those argument types. The dispatcher type-checks every argument on
    every call (about 0.2 us each with warm caches, several times that between two lock-step
    ticks), which for the world's 19-argument touch cost more than the touch. The caller keeps the
    arguments' types (dtype, dimensions, layout, writeability) the same from call to call."""

    def __init__(self, dispatcher):
        self.dispatcher, self.compiled = dispatcher, None

    def __call__(self, *args):
        if self.compiled is None:
            result = self.dispatcher(*args)
            self.compiled = self.dispatcher.overloads[tuple(typeof(a) for a in args)].entry_point
            return result
        return self.compiled(*args)


def compiled(dispatcher, signature: tuple):
    """The machine code of a numba function for these argument types (loaded from numba's cache
    or compiled now), to be called without the dispatcher's per-call type checks. The caller
    passes arguments of those types only: the compiled function does not check them."""
    return dispatcher.compile(signature)
