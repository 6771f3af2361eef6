"""Key expressions of the bus, all in one place.

Everything lives under `spikinglab/<group>/...`, where a group is one insect or one population of
A insects stepped together (one message carries the whole batch). Default group: "insect".
"""

PREFIX = "spikinglab"
DEFAULT_GROUP = "insect"
# in a liveliness token's name, <service>-waiting-<session id>: a process that is to be that service
# once it joins the bus (a world shard waiting for its lead), not on the bus as it yet
WAITING = "-waiting-"


def check_group(group: str) -> str:
    """`group` if it is one key segment, else ValueError saying what it may not hold."""
    if not group or any(c in group for c in "/*$?#@ "):
        raise ValueError(f"group name {group!r} must be one key segment (no '/', '*', '$', '?', '#', '@' or spaces)")
    return group


def sensors(group: str, shard: tuple[int, int] | None = None) -> str:
    """World (or robot gateway) -> brain: sensor values for one tick; to shard (i, n) of a sharded
    brain (n > 1), its slice of the agents."""
    if shard is None or shard[1] == 1:
        return f"{PREFIX}/{check_group(group)}/sensors"
    return f"{PREFIX}/{check_group(group)}/sensors/{shard_name(shard)}"


def shard_name(shard: tuple[int, int]) -> str:
    """Shard i of n (1-based), as keys and liveliness tokens name it: "2of3"."""
    return f"{shard[0]}of{shard[1]}"


def motor(group: str) -> str:
    """Brain -> world (or gateway): which actions fired in one tick."""
    return f"{PREFIX}/{check_group(group)}/motor"


def control(group: str) -> str:
    """Run control: end of run, training on/off."""
    return f"{PREFIX}/{check_group(group)}/control"


def brain_state(group: str) -> str:
    """Brain -> recorder: the layout once, then batches of spikes, potentials and weights."""
    return f"{PREFIX}/{check_group(group)}/state/brain"


def world_state(group: str) -> str:
    """World -> recorder: batches of poses, sensors, events and map changes."""
    return f"{PREFIX}/{check_group(group)}/state/world"


def world_map(group: str) -> str:
    """World -> recorder: the arena grid, at the start."""
    return f"{PREFIX}/{check_group(group)}/state/map"


def world_run(group: str) -> str:
    """World shard 1 -> the other world shards (world --shard I/N): the run they step together."""
    return f"{PREFIX}/{check_group(group)}/world/run"


def state(group: str) -> str:
    """Everything a recorder needs, and nothing of the lock-step traffic (sensors, motor)."""
    return f"{PREFIX}/{check_group(group)}/state/**"


def alive(group: str, service: str) -> str:
    """Liveliness token of a service (brain, world, gateway, recorder) of a group; "*": any."""
    return f"{PREFIX}/{check_group(group)}/alive/{service if service == '*' else check_group(service)}"


def world_service(shard: tuple[int, int]) -> str:
    """The name a world is alive under: "world" (a whole world, or world shard 1, which leads the
    others), or "world-2of3" for world shard 2 of 3."""
    return "world" if shard[0] == 1 else f"world-{shard_name(shard)}"


DONE = "-done"
# <service>-leaving: held by a service for the moment it leaves the bus of its own accord (its
# token then goes), so that the others tell an orderly end from a process killed or lost
LEAVING = "-leaving"


def world_done(shard: tuple[int, int]) -> str:
    """The name of the token world shard I of N holds once it has run its ticks: "world-2of3-done"."""
    return world_service(shard) + DONE


def brain_service(shard: tuple[int, int]) -> str:
    """The name a brain is alive under: "brain", or "brain-2of3" for shard 2 of 3."""
    return "brain" if shard[1] == 1 else f"brain-{shard_name(shard)}"
