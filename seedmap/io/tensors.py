"""Reading safetensors weight files into numpy, with the project's one-line errors.

One reader for every numpy-side weights file (the `fast` CNN refiner, the `fast` CNN training checkpoint):
a file that is missing, truncated or not safetensors raises :class:`~seedmap.errors.InputError` naming
the file, never a library traceback. Which kind of weights a file holds is the caller's check (the
``seedmap_kind`` metadata entry), because each caller words its own expectation.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from seedmap.errors import InputError


def read_safetensors(path: str | Path, what: str = "file") -> tuple[dict[str, np.ndarray], dict[str, str]]:
    """``(tensors, metadata)`` of a safetensors file; ``what`` names the file in the error message."""
    from safetensors import SafetensorError, safe_open

    p = Path(path)
    try:
        with safe_open(str(p), framework="numpy") as fh:
            meta = dict(fh.metadata() or {})
            tensors = {k: fh.get_tensor(k) for k in fh.keys()}
    except (SafetensorError, OSError, ValueError) as e:
        raise InputError(f"not a readable safetensors {what} ({str(e).splitlines()[0][:100]})", p) from None
    return tensors, meta
