"""The processes of spikinglab, one folder each (brain, world, ev3_gateway, recorder), the bus they
share (bus/), and what more than one of them uses. The user's front is the `spikinglab` package."""

from services.kernel_cache import use_cache_folder

use_cache_folder()  # before any module of services compiles a kernel
