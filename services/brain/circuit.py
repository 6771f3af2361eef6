"""Circuit files: a declarative description of a spiking network (services/brain/circuits/*.toml).

A circuit names its neuron types, neurons, input neurons, synapses, which sensor feeds which
input neuron and which actuator neuron triggers which action. `load_circuit` validates the whole
file before anything is built: a wrong file raises CircuitError naming the file, the entry and
what is wrong. The format is documented in docs/circuits.md.
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

CIRCUITS_DIR = Path(str(resources.files("services.brain") / "circuits"))  # shipped with the package


class CircuitError(ValueError):
    """A circuit file (or circuit description) is wrong; the message names file, entry and problem."""


@dataclass(frozen=True)
class NeuronType:
    """Parameters of one neuron type (the NetLogo source's types 1 and 2). Times are in ticks."""

    name: str
    rest: float = -65.0
    threshold: float = -55.0
    decay: float = 0.08  # fraction of the distance to rest removed per tick
    refractory_potential: float = -75.0
    refractory_period: int = 3
    floor: float = -75.0  # lowest membrane potential under inhibition
    a_plus: float = 0.02
    a_minus: float = 0.02
    tau_plus: float = 11.0
    tau_minus: float = 18.0
    window_neg: int = -50  # potentiation for window_neg <= dt <= 0
    window_pos: int = 75  # depression for 0 < dt <= window_pos
    w_min: float = 1.0
    w_max: float = 15.0


# The paper's two types: type 1 ("regular") and type 2 ("pacemaker").
BUILTIN_TYPES = {
    "regular": NeuronType("regular"),
    "pacemaker": NeuronType(
        "pacemaker",
        refractory_potential=-70.0,
        refractory_period=1,
        floor=-70.0,
        a_plus=0.09,
        a_minus=0.09,
        tau_plus=8.0,
        tau_minus=15.0,
        window_neg=-25,
        window_pos=55,
    ),
}


@dataclass(frozen=True)
class Synapse:
    pre: int  # node index: neurons first, then input neurons
    post: int  # always a regular neuron
    weight: float
    delay: int
    inhibitory: bool = False
    plastic: bool = False


@dataclass(frozen=True)
class InputNeuron:
    """A spike source: fed a value v it emits `pulses` pulses, each after a count of floor(v) + 1
    ticks (the feed's own tick counts as the first), so the first comes at t + floor(v)."""

    name: str
    target: str
    weight: float = 20.0
    delay: int = 0  # ticks; 0: the target gets the pulse in the tick it is sent (as in NetLogo)
    pulses: int = 1
    sensor: str | None = None  # the sensor that feeds it, if any
    at_start: float | None = None  # fed once with this value at tick 0 (the pacemaker kick)


@dataclass(frozen=True)
class Circuit:
    name: str
    source: str  # file path or "<built>"
    neuron_names: tuple[str, ...]
    neuron_types: tuple[NeuronType, ...]  # one per neuron
    inputs: tuple[InputNeuron, ...]
    synapses: tuple[Synapse, ...]  # network synapses first, then one per input neuron
    actuators: dict[str, str] = field(default_factory=dict)  # action -> neuron name

    @property
    def node_names(self) -> tuple[str, ...]:
        return self.neuron_names + tuple(i.name for i in self.inputs)

    def neuron_index(self, name: str) -> int:
        try:
            return self.neuron_names.index(name)
        except ValueError:
            raise KeyError(f"circuit {self.name!r} has no neuron {name!r}") from None

    def input_index(self, name: str) -> int:
        for k, inp in enumerate(self.inputs):
            if inp.name == name:
                return k
        raise KeyError(f"circuit {self.name!r} has no input neuron {name!r}")

    def synapse_index(self, pre: str, post: str) -> int:
        names = self.node_names
        for k, s in enumerate(self.synapses):
            if names[s.pre] == pre and names[s.post] == post:
                return k
        raise KeyError(f"circuit {self.name!r} has no synapse {pre} -> {post}")

    def synapse_label(self, k: int) -> str:
        s, names = self.synapses[k], self.node_names
        return f"{names[s.pre]}->{names[s.post]}"

    @property
    def sensors(self) -> dict[str, int]:
        """sensor name -> input neuron index."""
        return {inp.sensor: k for k, inp in enumerate(self.inputs) if inp.sensor}

    @property
    def plastic_synapses(self) -> list[int]:
        return [k for k, s in enumerate(self.synapses) if s.plastic]

    def with_learning_rate(self, a_plus: float, a_minus: float | None = None) -> Circuit:
        """Set A+ (and A-, default = A+) of every neuron type that is the target of a plastic synapse."""
        a_minus = a_plus if a_minus is None else a_minus
        for value, label in ((a_plus, "A+"), (a_minus, "A-")):
            if not (math.isfinite(value) and value >= 0):
                raise CircuitError(f"{self.source}: {label} must be a finite number >= 0, got {value}")
        return self.with_learning_params(a_plus=a_plus, a_minus=a_minus)

    def with_learning_params(self, **fields) -> Circuit:
        """Set NeuronType fields (w_max, tau_plus, ...) of every neuron that a plastic synapse targets."""
        learning = {self.synapses[k].post for k in self.plastic_synapses}
        types = []
        for n, t in enumerate(self.neuron_types):
            if n in learning:
                t = dataclasses.replace(t, **fields)
                _check_type(t, lambda problem, name=t.name: self._fail(f"type {name}: {problem}"))
            types.append(t)
        for k in self.plastic_synapses:
            t, w = types[self.synapses[k].post], self.synapses[k].weight
            if not t.w_min <= w <= t.w_max:
                self._fail(f"{self.synapse_label(k)}: weight {w} out of range [{t.w_min}, {t.w_max}]")
        return dataclasses.replace(self, neuron_types=tuple(types))

    def _fail(self, problem: str):
        raise CircuitError(f"{self.source}: {problem}")


def builtin_circuit_path(name: str) -> Path:
    return CIRCUITS_DIR / f"{name}.toml"


def load_circuit(path_or_name: str | Path) -> Circuit:
    """Load a circuit file; a bare name such as "insect" means services/brain/circuits/insect.toml."""
    path = Path(path_or_name)
    if path.suffix != ".toml" and not path.exists():
        path = builtin_circuit_path(str(path_or_name))
    try:
        text = path.read_text()
    except OSError as e:
        raise CircuitError(f"{path}: cannot read circuit file: {e.strerror or e}") from None
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise CircuitError(f"{path}: not valid TOML: {e}") from None
    return build_circuit(doc, source=str(path))


# --- validation -------------------------------------------------------------------------------

_TOP_KEYS = {"name", "about", "types", "neurons", "inputs", "synapses", "actuators"}
_TYPE_FIELDS = {f.name: f.type for f in dataclasses.fields(NeuronType) if f.name != "name"}
_INPUT_KEYS = {"target", "weight", "delay", "pulses", "sensor", "at_start"}
_SYNAPSE_KEYS = {"from", "to", "weight", "delay", "inhibitory", "plastic"}


def build_circuit(doc: dict, source: str = "<built>") -> Circuit:
    """Validate a parsed circuit document and build the Circuit (all or nothing), section by
    section as the model is described: neuron types, neurons, input neurons, synapses, actuators."""
    read = _Reader(source)
    read.keys("top level", doc, _TOP_KEYS)
    types = _neuron_types(read, doc.get("types", {}))
    neuron_names, neuron_types = _neurons(read, doc.get("neurons"), types)
    inputs = _inputs(read, doc.get("inputs", {}), neuron_names)
    synapses = _synapses(read, doc.get("synapses", []), neuron_names, neuron_types, inputs)
    actuators = _actuators(read, doc.get("actuators", {}), neuron_names)
    return Circuit(
        name=str(doc.get("name", Path(source).stem)),
        source=source,
        neuron_names=neuron_names,
        neuron_types=neuron_types,
        inputs=inputs,
        synapses=synapses,
        actuators=actuators,
    )


class _Reader:
    """Checks on one circuit document's values; each failure names the file and the entry."""

    def __init__(self, source: str):
        self.source = source

    def fail(self, entry: str, problem: str):
        raise CircuitError(f"{self.source}: {entry}: {problem}")

    def number(self, entry, key, value, *, integer=False):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            self.fail(entry, f"{key} must be a number, got {value!r}")
        if integer and (not float(value).is_integer()):
            self.fail(entry, f"{key} must be a whole number of ticks, got {value!r}")
        if not math.isfinite(value):
            self.fail(entry, f"{key} must be finite, got {value!r}")
        return int(value) if integer else float(value)

    def keys(self, entry, table, allowed=None):
        """A table, with only the allowed keys (None: any)."""
        if not isinstance(table, dict):
            self.fail(entry, f"must be a table, got {table!r}")
        extra = sorted(set(table) - allowed) if allowed is not None else []
        if extra:
            self.fail(entry, f"unknown key(s) {', '.join(extra)} (allowed: {', '.join(sorted(allowed))})")


def _neuron_types(read: _Reader, tables: dict) -> dict[str, NeuronType]:
    """The built-in types, then the file's own, each based on a built-in or an earlier type."""
    read.keys("types", tables)
    types = dict(BUILTIN_TYPES)
    for tname, table in tables.items():
        entry = f"types.{tname}"
        read.keys(entry, table, set(_TYPE_FIELDS) | {"base"})
        base_name = table.get("base", "regular")
        if base_name not in types:
            read.fail(entry, f"unknown base type {base_name!r} (known: {', '.join(types)})")
        values = {
            key: read.number(entry, key, value, integer=_TYPE_FIELDS[key] == "int")
            for key, value in table.items()
            if key != "base"
        }
        t = dataclasses.replace(types[base_name], name=tname, **values)
        _check_type(t, lambda p, entry=entry: read.fail(entry, p))
        types[tname] = t
    return types


def _neurons(read: _Reader, neurons, types: dict) -> tuple[tuple[str, ...], tuple[NeuronType, ...]]:
    """[neurons]: NAME = "type", in file order (the order is the neurons' index)."""
    if not isinstance(neurons, dict) or not neurons:
        read.fail("neurons", 'a circuit needs a [neurons] table with at least one neuron (NAME = "type")')
    for nname, tname in neurons.items():
        if not isinstance(tname, str) or tname not in types:
            read.fail(f"neurons.{nname}", f"unknown neuron type {tname!r} (known: {', '.join(types)})")
    return tuple(neurons), tuple(types[tname] for tname in neurons.values())


def _inputs(read: _Reader, tables: dict, neuron_names: tuple[str, ...]) -> tuple[InputNeuron, ...]:
    """[inputs.NAME]: spike sources, each with one synapse to its target and at most one sensor."""
    read.keys("inputs", tables)
    inputs = []
    for iname, table in tables.items():
        entry = f"inputs.{iname}"
        read.keys(entry, table, _INPUT_KEYS)
        if iname in neuron_names:
            read.fail(entry, f"duplicate name {iname!r}: already a neuron")
        target = table.get("target")
        if target not in neuron_names:
            read.fail(entry, f"unknown target neuron {target!r}")
        inp = InputNeuron(
            name=iname,
            target=target,
            weight=read.number(entry, "weight", table.get("weight", 20.0)),
            delay=read.number(entry, "delay", table.get("delay", 0), integer=True),
            pulses=read.number(entry, "pulses", table.get("pulses", 1), integer=True),
            sensor=table.get("sensor"),
            at_start=None if "at_start" not in table else read.number(entry, "at_start", table["at_start"]),
        )
        if inp.weight <= 0:
            read.fail(entry, f"weight must be > 0, got {inp.weight}")
        if inp.delay < 0:
            read.fail(entry, f"delay must be >= 0 ticks, got {inp.delay}")
        if inp.pulses < 1:
            read.fail(entry, f"pulses must be >= 1, got {inp.pulses}")
        if inp.at_start is not None and inp.at_start < 0:
            read.fail(entry, f"at_start must be >= 0, got {inp.at_start}")
        if inp.sensor is not None and not isinstance(inp.sensor, str):
            read.fail(entry, f"sensor must be a name, got {inp.sensor!r}")
        inputs.append(inp)
    sensors = [i.sensor for i in inputs if i.sensor]
    for s in sensors:
        if sensors.count(s) > 1:
            read.fail("inputs", f"sensor {s!r} feeds more than one input neuron")
    return tuple(inputs)


def _synapses(
    read: _Reader,
    raw,
    neuron_names: tuple[str, ...],
    neuron_types: tuple[NeuronType, ...],
    inputs: tuple[InputNeuron, ...],
) -> tuple[Synapse, ...]:
    """[[synapses]] between neurons (from/to: a name or a list of names, all pairs), then one
    synapse per input neuron to its target."""
    if not isinstance(raw, list):
        read.fail("synapses", "must be an array of tables ([[synapses]])")
    index = {n: k for k, n in enumerate(neuron_names + tuple(i.name for i in inputs))}
    synapses, seen = [], {}
    for k, table in enumerate(raw):
        entry = f"synapses[{k}]"
        read.keys(entry, table, _SYNAPSE_KEYS)
        for key in ("from", "to", "weight", "delay"):
            if key not in table:
                read.fail(entry, f"missing {key!r}")
        pres = table["from"] if isinstance(table["from"], list) else [table["from"]]
        posts = table["to"] if isinstance(table["to"], list) else [table["to"]]
        weight = read.number(entry, "weight", table["weight"])
        delay = read.number(entry, "delay", table["delay"], integer=True)
        inhibitory = table.get("inhibitory", False)
        plastic = table.get("plastic", False)
        for key, val in (("inhibitory", inhibitory), ("plastic", plastic)):
            if not isinstance(val, bool):
                read.fail(entry, f"{key} must be true or false, got {val!r}")
        if delay < 1:
            read.fail(entry, f"delay must be >= 1 tick, got {delay}")
        if weight <= 0:
            read.fail(entry, f"weight must be > 0 (use inhibitory = true for inhibition), got {weight}")
        if inhibitory and plastic:
            read.fail(entry, "inhibitory synapses are not plastic")
        for pre in pres:
            for post in posts:
                label = f"{entry} ({pre} -> {post})"
                if pre not in neuron_names:
                    what = (
                        "an input neuron (inputs have one synapse, to their target)"
                        if pre in index
                        else "unknown neuron"
                    )
                    read.fail(label, f"from: {what} {pre!r}")
                if post not in neuron_names:
                    read.fail(label, f"to: unknown neuron {post!r}")
                if (pre, post) in seen:
                    read.fail(label, f"duplicate synapse, already defined in {seen[(pre, post)]}")
                seen[(pre, post)] = entry
                t = neuron_types[index[post]]
                if plastic and not (t.w_min <= weight <= t.w_max):
                    read.fail(label, f"weight {weight} out of range [{t.w_min}, {t.w_max}] of type {t.name!r}")
                synapses.append(Synapse(index[pre], index[post], weight, delay, inhibitory, plastic))
    synapses += [Synapse(index[inp.name], index[inp.target], inp.weight, inp.delay) for inp in inputs]
    return tuple(synapses)


def _actuators(read: _Reader, actuators, neuron_names: tuple[str, ...]) -> dict[str, str]:
    """[actuators]: ACTION = "neuron" whose spike triggers that action."""
    read.keys("actuators", actuators)
    for action, nname in actuators.items():
        if nname not in neuron_names:
            read.fail(f"actuators.{action}", f"unknown neuron {nname!r}")
    return dict(actuators)


def _check_type(t: NeuronType, fail) -> None:
    if not t.floor <= t.rest < t.threshold:
        fail(f"need floor <= rest < threshold, got {t.floor}, {t.rest}, {t.threshold}")
    if not t.floor <= t.refractory_potential:  # the floor is the lowest potential a neuron can have
        fail(f"need floor <= refractory_potential, got {t.floor}, {t.refractory_potential}")
    if not 0 < t.decay < 1:
        fail(f"decay must be in (0, 1), got {t.decay}")
    if t.refractory_period < 0:
        fail(f"refractory_period must be >= 0, got {t.refractory_period}")
    if t.tau_plus <= 0 or t.tau_minus <= 0:
        fail("tau_plus and tau_minus must be > 0")
    if t.a_plus < 0 or t.a_minus < 0:
        fail("a_plus and a_minus must be >= 0")
    if not t.window_neg <= 0 <= t.window_pos:
        fail(f"need window_neg <= 0 <= window_pos, got {t.window_neg}, {t.window_pos}")
    if not 0 < t.w_min <= t.w_max:
        fail(f"need 0 < w_min <= w_max, got {t.w_min}, {t.w_max}")
