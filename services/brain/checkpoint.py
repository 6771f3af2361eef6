"""Checkpoints: a brain's weights in an .npz file, tied to the circuit's synapses by name."""

from __future__ import annotations

import logging
import zipfile
from pathlib import Path

import numpy as np

from services.snapshots import write_npz

from .circuit import Circuit
from .engine import Engine

log = logging.getLogger("spikinglab.brain")


def save_weights(path: Path, engine: Engine | np.ndarray, circuit: Circuit, tick: int = 0, say: bool = False) -> None:
    """An engine's weights, or weights [A, synapses] gathered from several (a brain serving a sharded world).
    `say`: log it (--save, in the lock-step and the free-running brain alike)."""
    labels = [circuit.synapse_label(k) for k in range(len(circuit.synapses))]
    weights = engine if isinstance(engine, np.ndarray) else engine.get_weights()
    write_npz(path, weights=weights, synapses=np.array(labels), circuit=circuit.name, tick=tick)
    if say:
        log.info("weights saved to %s", path)


def load_weights(path: Path, circuit: Circuit, say: bool = False, w_max: np.ndarray | None = None) -> np.ndarray:
    """Weights [A, synapses] from a checkpoint; its synapses must be the circuit's, in order, and
    its values ones the brain can take (check_values). `say`: log it (--load, in either brain)."""
    try:
        with np.load(path) as data:
            weights, labels = data["weights"], [str(x) for x in data["synapses"]]
    except (ValueError, zipfile.BadZipFile, EOFError) as e:  # numpy took it for a pickle: not an .npz at all
        raise ValueError(
            f"{path}: not a weights file (not an .npz archive: truncated, or another kind of file; {type(e).__name__})"
        ) from None
    except KeyError:
        raise ValueError(
            f"{path}: not a weights file (an .npz without the arrays weights and synapses: a run's "
            "weights.npz, or what `spikinglab brain --save` writes)"
        ) from None
    except OSError as e:
        raise ValueError(f"{path}: cannot read it ({e.strerror or e})") from None
    expected = [circuit.synapse_label(k) for k in range(len(circuit.synapses))]
    if labels != expected:
        missing = sorted(set(expected) - set(labels)) or sorted(set(labels) - set(expected))
        raise ValueError(f"{path}: its synapses do not match circuit {circuit.name!r} (differ in: {missing[:5]})")
    if weights.ndim != 2 or weights.shape[1] != len(expected):
        raise ValueError(f"{path}: weights have shape {weights.shape}, expected (agents, {len(expected)})")
    check_values(path, weights, circuit, w_max)
    if say:
        log.info("weights loaded from %s (%d agent%s)", path, len(weights), "" if len(weights) == 1 else "s")
    return weights


def check_values(path: Path, weights: np.ndarray, circuit: Circuit, w_max: np.ndarray | None) -> None:
    """Every weight a number > 0, and a plastic synapse's within its neuron type's [w_min, w_max];
    `w_max`: a --params file's, one per agent (it sets every learning neuron's)."""
    if not np.issubdtype(weights.dtype, np.number) or not np.all(np.isfinite(weights)) or np.any(weights <= 0):
        raise ValueError(f"{path}: weights must be finite numbers > 0")
    fits = w_max is not None and (len(weights) == 1 or len(weights) == len(w_max))  # else refused for its agents
    for k in circuit.plastic_synapses:
        t = circuit.neuron_types[circuit.synapses[k].post]
        high = np.asarray(w_max, np.float64) if fits else np.array([t.w_max])
        given = np.broadcast_to(weights[:, k], np.broadcast_shapes(weights[:, k].shape, high.shape))
        bad = np.nonzero((given < t.w_min) | (given > high))[0]
        if bad.size:
            a = int(bad[0])
            raise ValueError(
                f"{path}: weight {given[a]} of plastic synapse {circuit.synapse_label(k)} of agent {a} outside "
                f"[{t.w_min}, {high[a if high.size > 1 else 0]}]" + (" (w_max of the --params file)" if fits else "")
            )
