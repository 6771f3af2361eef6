"""Circuit files: a declarative description of a spiking network (services/brain/circuits/*.toml).

A circuit names its neuron types, neurons, input neurons, synapses, which sensor feeds which
input neuron and which actuator neuron triggers which action. `load_circuit` validates the whole
file before anything is built: a wrong file raises CircuitError naming the file, the entry and
what is wrong. The format is documented in docs/circuits.md.
"""

from __future__ import annotations

import dataclasses
import math
import re
import tomllib
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any, NoReturn

import msgspec

from services.params import is_number

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

    @property
    def learning_neurons(self) -> set[int]:
        """The neurons that a plastic synapse targets: those whose learning values a study sets, and
        the only ones that ever remember arrivals."""
        return {self.synapses[k].post for k in self.plastic_synapses}

    def with_learning_rate(self, a_plus: float, a_minus: float | None = None) -> Circuit:
        """Set A+ (and A-, default = A+) of every neuron type that is the target of a plastic synapse."""
        a_minus = a_plus if a_minus is None else a_minus
        for value, label in ((a_plus, "A+"), (a_minus, "A-")):
            if not (is_number(value) and value >= 0):
                raise CircuitError(f"{self.source}: {label} must be a finite number >= 0, got {value!r}")
        return self.with_learning_params(a_plus=a_plus, a_minus=a_minus)

    def with_learning_params(self, **fields) -> Circuit:
        """Set NeuronType fields (w_max, tau_plus, ...) of every neuron that a plastic synapse targets."""
        known = [f.name for f in dataclasses.fields(NeuronType)[1:]]
        if unknown := sorted(set(fields) - set(known)):
            raise CircuitError(f"{self.source}: unknown learning value {unknown[0]!r} (known: {', '.join(known)})")
        learning = self.learning_neurons
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
    if not isinstance(path_or_name, str | Path):
        raise TypeError(f"load_circuit: a circuit's name or file, e.g. 'insect', got {path_or_name!r}")
    path = Path(path_or_name)
    if path.suffix != ".toml" and not path.exists():
        path = builtin_circuit_path(str(path_or_name))
    try:
        text = path.read_text()
    except OSError as e:
        raise CircuitError(f"{path}: cannot read circuit file: {e.strerror or e}") from None
    except UnicodeDecodeError:
        raise CircuitError(f"{path}: not a circuit file (not text: a circuit is a TOML file)") from None
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise CircuitError(f"{path}: not valid TOML: {e}") from None
    return build_circuit(doc, source=str(path))


# --- validation: msgspec structs check each table's keys and value types; the functions after them
# check what the values mean. Numbers are floats (TOML integers are taken too); the whole numbers
# of ticks are checked after, so that 3.0 is 3.


class _File(msgspec.Struct, forbid_unknown_fields=True):
    """The top level. Its sections are checked entry by entry, so that an error names the entry."""

    name: str | None = None
    about: str | None = None
    types: dict[str, Any] = {}
    neurons: dict[str, Any] = {}
    inputs: dict[str, Any] = {}
    synapses: list[Any] = []
    actuators: dict[str, Any] = {}


_TypeTable = msgspec.defstruct(
    "_TypeTable",
    [("base", str, "regular")]
    + [(f.name, float | None, None) for f in dataclasses.fields(NeuronType) if f.name != "name"],
    forbid_unknown_fields=True,
)
_TYPE_INTEGERS = {f.name for f in dataclasses.fields(NeuronType) if f.type == "int"}


class _InputTable(msgspec.Struct, forbid_unknown_fields=True):
    target: str
    weight: float = 20.0
    delay: float = 0
    pulses: float = 1
    sensor: str | None = None
    at_start: float | None = None


class _SynapseTable(msgspec.Struct, forbid_unknown_fields=True):
    from_: str | list[str] = msgspec.field(name="from")
    to: str | list[str]
    weight: float
    delay: float
    inhibitory: bool = False
    plastic: bool = False


# what a field's type asks for, in the words of an error message
_KINDS = {
    float: "a number",
    float | None: "a number",
    str: "a string",
    str | None: "a string",
    bool: "true or false",
    str | list[str]: "a name or a list of names",
    dict[str, Any]: "a table",
    list[Any]: "an array of tables ([[synapses]])",
}


class _Checker:
    """Turns one circuit document's tables into structs; each failure names the file and the entry."""

    def __init__(self, source: str):
        self.source = source

    def fail(self, entry: str, problem: str) -> NoReturn:
        raise CircuitError(f"{self.source}: {entry}: {problem}")

    def table(self, entry: str, raw, cls):
        """`raw` (a parsed TOML value) as a `cls` struct."""
        try:
            return msgspec.convert(raw, cls)
        except msgspec.ValidationError as e:
            raise CircuitError(f"{self.source}: {_said(str(e), entry, raw, cls)}") from None

    def numbers(self, entry: str, table, integers=()) -> dict:
        """The struct's fields, numbers checked: finite, and whole for the fields in `integers`."""
        values = msgspec.structs.asdict(table)
        for key, value in values.items():
            if not isinstance(value, float):
                continue
            if key in integers:
                if not value.is_integer():
                    self.fail(entry, f"{key} must be a whole number of ticks, got {value!r}")
                values[key] = int(value)
            elif not math.isfinite(value):
                self.fail(entry, f"{key} must be finite, got {value!r}")
        return values


def _said(error: str, entry: str, raw, cls) -> str:
    """msgspec's error for the entry `raw`, as 'entry: problem' in this module's words."""
    text, _, path = error.partition(" - at `$")
    fields = {f.encode_name: f for f in msgspec.structs.fields(cls)}
    at = re.match(r"\.(\w+)", path)
    key = at.group(1) if at else ""  # the field at fault, "" for the table itself
    if key in fields:
        kind, value = _KINDS.get(fields[key].type, f"of type {fields[key].type}"), raw[key]
        # a section of the top level is an entry of its own
        return (
            f"{key}: must be {kind}, got {value!r}" if cls is _File else f"{entry}: {key} must be {kind}, got {value!r}"
        )
    if text.startswith("Object contains unknown field"):
        extra = ", ".join(sorted(set(raw) - set(fields)))
        return f"{entry}: unknown key(s) {extra} (allowed: {', '.join(sorted(fields))})"
    if missing := re.match(r"Object missing required field `(\w+)`", text):
        return f"{entry}: missing {missing.group(1)!r}"
    if text.startswith("Expected `object`"):
        return f"{entry}: must be a table, got {raw!r}"
    return f"{entry}: {text}"


def build_circuit(doc: dict, source: str = "<built>") -> Circuit:
    """Validate a parsed circuit document and build the Circuit (all or nothing), section by
    section as the model is described: neuron types, neurons, input neurons, synapses, actuators."""
    check = _Checker(source)
    top = check.table("top level", doc, _File)
    types = _neuron_types(check, top.types)
    neuron_names, neuron_types = _neurons(check, top.neurons, types)
    inputs = _inputs(check, top.inputs, neuron_names)
    synapses = _synapses(check, top.synapses, neuron_names, neuron_types, inputs)
    actuators = _actuators(check, top.actuators, neuron_names)
    return Circuit(
        name=Path(source).stem if top.name is None else top.name,
        source=source,
        neuron_names=neuron_names,
        neuron_types=neuron_types,
        inputs=inputs,
        synapses=synapses,
        actuators=actuators,
    )


def _neuron_types(check: _Checker, tables: dict) -> dict[str, NeuronType]:
    """The built-in types, then the file's own, each based on a built-in or an earlier type."""
    types = dict(BUILTIN_TYPES)
    for tname, raw in tables.items():
        entry = f"types.{tname}"
        table = check.table(entry, raw, _TypeTable)
        if table.base not in types:
            check.fail(entry, f"unknown base type {table.base!r} (known: {', '.join(types)})")
        values = check.numbers(entry, table, _TYPE_INTEGERS)
        fields = {key: value for key, value in values.items() if key != "base" and value is not None}
        t = dataclasses.replace(types[table.base], name=tname, **fields)
        _check_type(t, lambda p, entry=entry: check.fail(entry, p))
        types[tname] = t
    return types


def _neurons(check: _Checker, neurons: dict, types: dict) -> tuple[tuple[str, ...], tuple[NeuronType, ...]]:
    """[neurons]: NAME = "type", in file order (the order is the neurons' index)."""
    if not neurons:
        check.fail("neurons", 'a circuit needs a [neurons] table with at least one neuron (NAME = "type")')
    for nname, tname in neurons.items():
        if not isinstance(tname, str) or tname not in types:
            check.fail(f"neurons.{nname}", f"unknown neuron type {tname!r} (known: {', '.join(types)})")
    return tuple(neurons), tuple(types[tname] for tname in neurons.values())


def _inputs(check: _Checker, tables: dict, neuron_names: tuple[str, ...]) -> tuple[InputNeuron, ...]:
    """[inputs.NAME]: spike sources, each with one synapse to its target and at most one sensor."""
    inputs = []
    for iname, raw in tables.items():
        entry = f"inputs.{iname}"
        table = check.table(entry, raw, _InputTable)
        if iname in neuron_names:
            check.fail(entry, f"duplicate name {iname!r}: already a neuron")
        if table.target not in neuron_names:
            check.fail(entry, f"unknown target neuron {table.target!r}")
        inp = InputNeuron(name=iname, **check.numbers(entry, table, ("delay", "pulses")))
        if inp.weight <= 0:
            check.fail(entry, f"weight must be > 0, got {inp.weight}")
        if inp.delay < 0:
            check.fail(entry, f"delay must be >= 0 ticks, got {inp.delay}")
        if inp.pulses < 1:
            check.fail(entry, f"pulses must be >= 1, got {inp.pulses}")
        if inp.at_start is not None and inp.at_start < 0:
            check.fail(entry, f"at_start must be >= 0, got {inp.at_start}")
        inputs.append(inp)
    sensors = [i.sensor for i in inputs if i.sensor]
    for s in sensors:
        if sensors.count(s) > 1:
            check.fail("inputs", f"sensor {s!r} feeds more than one input neuron")
    return tuple(inputs)


def _synapses(
    check: _Checker,
    tables: list,
    neuron_names: tuple[str, ...],
    neuron_types: tuple[NeuronType, ...],
    inputs: tuple[InputNeuron, ...],
) -> tuple[Synapse, ...]:
    """[[synapses]] between neurons (from/to: a name or a list of names, all pairs), then one
    synapse per input neuron to its target."""
    index = {n: k for k, n in enumerate(neuron_names + tuple(i.name for i in inputs))}
    synapses, seen = [], {}
    for k, raw in enumerate(tables):
        entry = f"synapses[{k}]"
        table = check.table(entry, raw, _SynapseTable)
        values = check.numbers(entry, table, ("delay",))
        weight, delay = values["weight"], values["delay"]
        if delay < 1:
            check.fail(entry, f"delay must be >= 1 tick, got {delay}")
        if weight <= 0:
            check.fail(entry, f"weight must be > 0 (use inhibitory = true for inhibition), got {weight}")
        if table.inhibitory and table.plastic:
            check.fail(entry, "inhibitory synapses are not plastic")
        pres = table.from_ if isinstance(table.from_, list) else [table.from_]
        posts = table.to if isinstance(table.to, list) else [table.to]
        for pre in pres:
            for post in posts:
                label = f"{entry} ({pre} -> {post})"
                _check_pair(check, label, pre, post, index, neuron_names)
                if (pre, post) in seen:
                    check.fail(label, f"duplicate synapse, already defined in {seen[(pre, post)]}")
                seen[(pre, post)] = entry
                t = neuron_types[index[post]]
                if table.plastic and not (t.w_min <= weight <= t.w_max):
                    check.fail(label, f"weight {weight} out of range [{t.w_min}, {t.w_max}] of type {t.name!r}")
                synapses.append(Synapse(index[pre], index[post], weight, delay, table.inhibitory, table.plastic))
    synapses += [Synapse(index[inp.name], index[inp.target], inp.weight, inp.delay) for inp in inputs]
    return tuple(synapses)


def _check_pair(check: _Checker, label: str, pre: str, post: str, index: dict, neuron_names: tuple[str, ...]):
    """A synapse runs from a neuron (not an input neuron) to a neuron."""
    if pre not in neuron_names:
        what = "an input neuron (inputs have one synapse, to their target)" if pre in index else "unknown neuron"
        check.fail(label, f"from: {what} {pre!r}")
    if post not in neuron_names:
        check.fail(label, f"to: unknown neuron {post!r}")


def _actuators(check: _Checker, actuators: dict, neuron_names: tuple[str, ...]) -> dict[str, str]:
    """[actuators]: ACTION = "neuron" whose spike triggers that action."""
    for action, nname in actuators.items():
        if nname not in neuron_names:
            check.fail(f"actuators.{action}", f"unknown neuron {nname!r}")
    return dict(actuators)


WHOLE_FIELDS = ("refractory_period", "window_neg", "window_pos")  # in ticks
LONGEST_WINDOW = 100_000  # ticks each side: the W(dt) table holds a value per tick of the window


def _check_type(t: NeuronType, fail) -> None:
    for f in dataclasses.fields(t)[1:]:  # every field but the name is a number
        value = getattr(t, f.name)
        if not is_number(value):
            fail(f"{f.name} must be a finite number, got {value!r}")
        if f.name in WHOLE_FIELDS and value != int(value):
            fail(f"{f.name} must be a whole number of ticks, got {value!r}")
    if max(-t.window_neg, t.window_pos) > LONGEST_WINDOW:
        fail(f"the STDP window is at most {LONGEST_WINDOW:,} ticks each side, got {t.window_neg}..{t.window_pos}")
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
