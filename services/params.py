"""Per-agent parameters: what a study varies across the insects of one population.

Each is one column, a value per agent, declared here once: the engine reads the brain's, the
world the world's. A column that is not given keeps the circuit's (or the world's) own value for
every agent. Agents with the same brain values share one STDP table, so a population of a few
settings costs no more than one setting.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np


@dataclass(frozen=True)
class AgentParam:
    name: str
    side: str  # "brain" or "world": who reads it
    what: str
    positive: bool = True  # > 0 (else >= 0)


AGENT_PARAMS = {
    p.name: p
    for p in (
        AgentParam("a_plus", "brain", "A+: potentiation of the learning neurons' plastic synapses", positive=False),
        AgentParam("a_minus", "brain", "A-: depression of the learning neurons' plastic synapses", positive=False),
        AgentParam("tau_plus", "brain", "tau+: the potentiation window's time constant, ticks"),
        AgentParam("tau_minus", "brain", "tau-: the depression window's time constant, ticks"),
        AgentParam("w_max", "brain", "the largest weight of a plastic synapse"),
        AgentParam("initial_weight", "brain", "the weight every plastic synapse starts with"),
        AgentParam(
            "input_gain",
            "brain",
            "factor on the weight of every sensor-fed input neuron's synapse: "
            "how hard a sensed value drives its neuron",
        ),
        AgentParam("rotation_step", "world", "degrees turned per ROTATE spike"),
        AgentParam("move_step", "world", "patches moved per MOVE spike"),
    )
}


def is_int(value) -> bool:
    """An int of Python or numpy, not a bool: what a count of agents or ticks, or a seed, must be."""
    return isinstance(value, int | np.integer) and not isinstance(value, bool)


def is_number(value) -> bool:
    """A finite number of Python or numpy, not a bool: what a parameter's value must be."""
    return (
        isinstance(value, int | float | np.integer | np.floating)
        and not isinstance(value, bool)
        and math.isfinite(value)
    )


PARALLEL_FROM = 256  # agents; from here, engine and world kernels run across cores (below, thread start-up costs more)
# the NeuronType fields the learning columns set, on every neuron a plastic synapse targets
LEARNING_FIELDS = ("a_plus", "a_minus", "tau_plus", "tau_minus", "w_max")


class AgentValueError(ValueError):
    """A per-agent value out of range: `agent` is its row."""

    def __init__(self, text: str, agent: int):
        super().__init__(text)
        self.agent = agent


def agent_columns(agents: int, params: Mapping | None, side: str | None = None) -> dict[str, np.ndarray]:
    """The given columns as float arrays [agents] (a number: the same for all), checked.

    `side`: the columns are for that side only ("brain" or "world"). ValueError names an unknown
    column, one of the other side, a column of the wrong length, or a value out of range."""
    out = {}
    for name, values in (params or {}).items():
        if name not in AGENT_PARAMS:
            raise ValueError(f"unknown per-agent parameter {name!r} (known: {', '.join(AGENT_PARAMS)})")
        p = AGENT_PARAMS[name]
        if side is not None and p.side != side:
            raise ValueError(f"per-agent parameter {name} is the {p.side}'s, not the {side}'s")
        try:
            numbers = np.asarray(values, dtype=np.float64)
        except (ValueError, TypeError):
            raise ValueError(f"per-agent parameter {name}: numbers, got {values!r}"[:200]) from None
        try:
            column = np.broadcast_to(numbers, (agents,)).copy()
        except ValueError:
            raise ValueError(
                f"per-agent parameter {name}: {np.shape(values)} values for {agents} agents "
                f"(give one, or one per agent)"
            ) from None
        bad = ~np.isfinite(column) | ((column <= 0) if p.positive else (column < 0))
        if bad.any():
            k = int(np.flatnonzero(bad)[0])
            raise AgentValueError(
                f"per-agent parameter {name}: agent {k} has {column[k]}, it must be a finite number "
                f"{'>' if p.positive else '>='} 0",
                k,
            )
        out[name] = column
    return out


def grid(**values) -> dict[str, np.ndarray]:
    """Every combination of the values given per parameter, as columns (the first varies slowest):
    grid(a_plus=[0.01, 0.02], w_max=[10, 15]) -> 4 settings."""
    mesh = np.meshgrid(*[np.atleast_1d(np.asarray(v, dtype=np.float64)) for v in values.values()], indexing="ij")
    return {name: m.ravel() for name, m in zip(values, mesh)}


def setting_count(params: Mapping) -> int:
    """How many settings the columns give: their common length (1 if all are single numbers)."""
    lengths = {len(np.atleast_1d(v)) for v in params.values()} - {1}
    if len(lengths) > 1:
        raise ValueError(f"parameter columns of different lengths: {sorted(lengths)}")
    return lengths.pop() if lengths else 1


def param_lines(path: Path) -> list[tuple[int, list[str]]]:
    """A --params file's header and rows of values, each with its line number; blank lines and
    lines starting with # are skipped. ValueError where it cannot be read or holds no row."""
    try:
        with open(path, newline="", encoding="utf-8-sig") as f:  # a spreadsheet's CSV may start with a BOM
            lines = [
                (n, row)
                for n, row in enumerate(csv.reader(f), 1)
                if row and "".join(row).strip() and not row[0].lstrip().startswith("#")
            ]
    except OSError as e:
        raise ValueError(f"parameter file {path}: cannot read it ({e.strerror or e})") from None
    except (UnicodeDecodeError, csv.Error) as e:
        raise ValueError(f"parameter file {path}: not a CSV text file ({e})") from None
    if len(lines) < 2:
        raise ValueError(
            f"parameter file {path}: expected a header of parameter names and at least one row of "
            f"values (e.g. a_plus,w_max / 0.02,15)"
        )
    return lines


def agent_line(path: Path, agent: int) -> int:
    """The line of a --params file that holds `agent`'s values (its only row, where it has one)."""
    rows = param_lines(path)[1:]
    return rows[agent if len(rows) > 1 else 0][0]


def read_params(path: Path) -> dict[str, np.ndarray]:
    """Per-agent parameters from a CSV file (`--params`, param_lines): a header of parameter names,
    then one row of numbers per agent, or a single row for every agent. The columns, each as long
    as the rows; ValueError names the file, line and fault."""
    (_, header), *rows = lines = param_lines(path)
    names = [name.strip() for name in header]
    if len(set(names)) < len(names):
        raise ValueError(f"parameter file {path}, line {lines[0][0]}: a parameter named twice ({', '.join(names)})")
    values = np.empty((len(rows), len(names)))
    for k, (n, row) in enumerate(rows):
        if len(row) != len(names):
            raise ValueError(f"parameter file {path}, line {n}: {len(row)} values for {len(names)} parameters")
        for j, text in enumerate(row):
            try:
                values[k, j] = float(text)
            except ValueError:
                raise ValueError(
                    f"parameter file {path}, line {n}: {names[j]} is {text.strip()!r}, not a number"
                ) from None
    try:
        return agent_columns(len(rows), dict(zip(names, values.T)))
    except AgentValueError as e:
        raise ValueError(f"parameter file {path}, line {rows[e.agent][0]}: {e}") from None
    except ValueError as e:
        raise ValueError(f"parameter file {path}: {e}") from None


def file_rows(columns: Mapping) -> int:
    """The rows of read_params' columns (each has as many: at least one)."""
    return len(next(iter(columns.values())))


def side_of(columns: Mapping, side: str) -> dict:
    """The columns that `side` ("brain" or "world") reads."""
    return {name: values for name, values in columns.items() if AGENT_PARAMS[name].side == side}


def file_for_agents(path: Path, agents: int, said_by: str = "--agents") -> dict[str, np.ndarray]:
    """read_params, checked to fit a population of `agents` (one row for all, or one per agent);
    `said_by`: where the number of agents was given, for the error."""
    columns = read_params(path)
    rows = file_rows(columns)
    if rows not in (1, agents):
        raise ValueError(
            f"parameter file {path}: {rows} rows of values for {agents} agent{'s' * (agents != 1)} ({said_by}): "
            f"give one row for all of them, or one per agent"
        )
    return columns
