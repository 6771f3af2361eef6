"""Key expressions of the bus, all in one place.

Everything lives under `spikinglab/<group>/...`, where a group is one insect or one population of
A insects stepped together (one message carries the whole batch). Default group: "insect".
"""

PREFIX = "spikinglab"
DEFAULT_GROUP = "insect"


def _check(group: str) -> str:
    if not group or any(c in group for c in "/*$?#@ ") :
        raise ValueError(f"group name {group!r} must be one key segment (no '/', '*', '$', '?', '#', '@' or spaces)")
    return group


def sensors(group: str) -> str:
    """World (or robot gateway) -> brain: sensor values for one tick."""
    return f"{PREFIX}/{_check(group)}/sensors"


def motor(group: str) -> str:
    """Brain -> world (or gateway): which actions fired in one tick."""
    return f"{PREFIX}/{_check(group)}/motor"


def control(group: str) -> str:
    """Run control: end of run, training on/off."""
    return f"{PREFIX}/{_check(group)}/control"


def brain_state(group: str) -> str:
    """Brain -> recorder: spikes, potentials, weights."""
    return f"{PREFIX}/{_check(group)}/brain/state"


def world_state(group: str) -> str:
    """World -> recorder: poses, events, metrics."""
    return f"{PREFIX}/{_check(group)}/world/state"


def world_map(group: str) -> str:
    """World -> recorder: the arena grid, sent again whenever it changes."""
    return f"{PREFIX}/{_check(group)}/world/map"


def alive(group: str, service: str) -> str:
    """Liveliness token of a service (brain, world, gateway, recorder) of a group."""
    return f"{PREFIX}/{_check(group)}/alive/{_check(service)}"


def everything(group: str = "*") -> str:
    return f"{PREFIX}/{group}/**"
