"""Reading rerun recordings back in tests (shared by the rerun test files)."""

from __future__ import annotations


def rrd_column(path, entity: str, name: str) -> list:
    """Every value of component column ``name`` logged to ``entity`` in the .rrd file ``path``."""
    from rerun.chunk import RrdReader

    rows = []
    for ch in RrdReader(str(path)).stream():
        if ch.entity_path == entity:
            rb = ch.to_record_batch()
            if name in rb.schema.names:
                rows += rb.column(name).to_pylist()
    return rows
