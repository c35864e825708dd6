"""Dataloaders (one per format) and every file format seedmap reads or writes.

Every dataloader exposes the same small interface (:class:`StereoSequence`): ``calib``,
``timestamps``, ``len()``, ``[i] -> StereoFrame``, and ``gt_trajectory()`` (``None`` without GT).
:func:`open_dataset` picks the loader from the path.
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable, Protocol, runtime_checkable

import numpy as np

from seedmap.errors import InputError
from seedmap.records import StereoCalib, StereoFrame, Trajectory


@runtime_checkable
class StereoSequence(Protocol):
    name: str
    calib: StereoCalib
    timestamps: np.ndarray

    def __len__(self) -> int: ...

    def __getitem__(self, i: int) -> StereoFrame: ...

    def gt_trajectory(self) -> Trajectory | None: ...


# (name, detector(path) -> bool, opener(path, **kw) -> StereoSequence), tried in order.
_LOADERS: list[tuple[str, Callable[[Path], bool], Callable[..., StereoSequence]]] = []


def register_loader(name: str, detect: Callable[[Path], bool], opener: Callable[..., StereoSequence]) -> None:
    _LOADERS.append((name, detect, opener))


def loader_names() -> list[str]:
    return [n for n, _, _ in _LOADERS]


def open_dataset(path: str | Path, fmt: str | None = None, **kwargs) -> StereoSequence:
    """Open any supported stereo dataset; ``fmt`` forces a loader by name."""
    p = Path(path)
    if not p.exists():
        raise InputError("dataset not found", p)
    for name, detect, opener in _LOADERS:
        if (fmt is None and detect(p)) or fmt == name:
            return opener(p, **kwargs)
    if fmt is not None:
        raise InputError(f"unknown dataset format {fmt!r} (known: {', '.join(loader_names())})", p)
    raise InputError(f"no loader recognises this path (known formats: {', '.join(loader_names())})", p)


def _register_builtin() -> None:
    from seedmap.io.seedmap_dataset import SeedmapDataset

    register_loader("seedmap", SeedmapDataset.is_dataset, lambda p, **kw: SeedmapDataset(p))


_register_builtin()
