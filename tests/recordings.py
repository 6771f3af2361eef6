"""A run's Rerun recording (.rrd) read back as plain columns, for the tests of what it holds."""

from __future__ import annotations

from collections import defaultdict

import numpy as np
from rerun.chunk import RrdReader


def read(path):
    """{entity: {column: [values per row]}} with rows of all chunks in tick order; static data
    (styles, annotation contexts) under "<entity> static"."""
    rows = defaultdict(lambda: defaultdict(list))
    for chunk in RrdReader(str(path)).stream():
        batch = chunk.to_record_batch()
        entity = chunk.entity_path if "tick" in batch.schema.names else f"{chunk.entity_path} static"
        for name in batch.schema.names:
            if name == "tick" or (":" in name and not name.startswith("rerun.")):  # not log_time, row ids
                rows[entity][name] += batch.column(name).to_pylist()
    out = {}
    for entity, cols in rows.items():
        if "tick" in cols and all(t is not None for t in cols["tick"]):
            order = np.argsort(cols["tick"], kind="stable")
            cols = {k: [v[i] for i in order] for k, v in cols.items()}
        out[entity] = cols
    return out
