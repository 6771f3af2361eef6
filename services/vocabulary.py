"""The insect's words, shared by world, brain, gateway and recorder: what it senses, what it
does, the colours of its world's patches and the columns of its events. Knows no bus."""

# The insect's senses and actions: what a world or a robot gateway publishes and takes. The brain
# binds them to its circuit by name (circuit files: `sensor = ...`, [actuators]).
INSECT_SENSORS = ("smell_black", "smell_red", "smell_green", "pain", "reward")
INSECT_ACTIONS = ("rotate", "move")
# Patch colours in WorldMap grids and WorldState changes and events.
EMPTY, BLACK, RED, GREEN = 0, 1, 2, 3
# WorldState events columns: the colour of a collision entered this tick (0: none), food eaten,
# put back at the start, learning time reached.
EVENT_COLUMNS = ("collision", "ate", "reset", "learned")
EV_COLLISION, EV_ATE, EV_RESET, EV_LEARNED = range(len(EVENT_COLUMNS))
