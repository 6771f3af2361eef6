"""Whole-state checkpoints of a run, so that a restarted world or brain resumes it tick for tick.

A checkpoint is an .npz of the arrays that World.snapshot() or Engine.snapshot() give, plus `meta`
(JSON: which run, which tick, which options made it). restore() copies the arrays back in place,
so the numba kernels' views of them stay valid (a pickle would turn views into copies). Written to
a temporary file and then renamed: never a half-written checkpoint.
"""

from __future__ import annotations

import json
import zipfile
from pathlib import Path

import numpy as np


def write(path: Path, arrays: dict[str, np.ndarray], meta: dict) -> None:
    write_npz(path, meta=json.dumps(meta), **{f"a.{k}": v for k, v in arrays.items()})


def write_npz(path: Path, **arrays) -> None:
    """np.savez to a temporary file, then renamed: a reader never sees a half-written file."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp.npz")
    np.savez(tmp, **arrays)
    tmp.replace(path)


def read(path: Path) -> tuple[dict[str, np.ndarray], dict]:
    """(arrays, meta) of a checkpoint; ValueError naming the file when it is not one."""
    try:
        with np.load(path) as data:
            meta = json.loads(str(data["meta"]))
            arrays = {k[2:]: data[k] for k in data.files if k.startswith("a.")}
    except (ValueError, zipfile.BadZipFile, EOFError, KeyError):
        raise ValueError(f"{path}: not a run checkpoint (truncated, or another kind of file)") from None
    except OSError as e:
        raise ValueError(f"{path}: cannot read it ({e.strerror or e})") from None
    return arrays, meta


def copy_into(targets: dict[str, np.ndarray], arrays: dict[str, np.ndarray], what: str) -> None:
    """Copy each of `arrays` into the array of the same name in `targets`, in place; ValueError
    (naming `what`) unless the names, shapes and types match exactly."""
    if set(arrays) != set(targets):
        raise ValueError(f"{what}: holds {sorted(arrays)}, expected {sorted(targets)}")
    for name, target in targets.items():
        got = arrays[name]
        if got.shape != target.shape or got.dtype != target.dtype:
            raise ValueError(
                f"{what}: {name} is {got.dtype}{list(got.shape)}, this run has "
                f"{target.dtype}{list(target.shape)} (other agents, circuit or map)"
            )
    for name, target in targets.items():
        target[...] = arrays[name]
