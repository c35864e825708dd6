"""The dataset-format registry: every loader registers a name, a path test and an opener; :func:`open_dataset` picks one.

Loaders register themselves when their module is imported (the package root :mod:`seedmap.io` imports them all);
this module imports no loader.
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable, Protocol, runtime_checkable

import numpy as np

from seedmap.errors import ConfigError, InputError
from seedmap.records import StereoCalib, StereoFrame, Trajectory


@runtime_checkable
class StereoSequence(Protocol):
    name: str
    calib: StereoCalib
    timestamps: np.ndarray

    def __len__(self) -> int: ...

    def __getitem__(self, i: int) -> StereoFrame: ...

    def gt_trajectory(self) -> Trajectory | None: ...


# (order, name, detector(path) -> bool, opener(path, **kw) -> StereoSequence), tried by ascending order.
_LOADERS: list[tuple[int, str, Callable[[Path], bool], Callable[..., StereoSequence]]] = []


def register_loader(name: str, detect: Callable[[Path], bool], opener: Callable[..., StereoSequence],
                    order: int = 100) -> None:
    """Make format ``name`` available: ``detect(path)`` says whether a path has it, ``opener(path, **options)`` opens
    it. Formats are tried by ascending ``order`` (a more specific layout first)."""
    _LOADERS[:] = sorted([x for x in _LOADERS if x[1] != name] + [(order, name, detect, opener)],
                         key=lambda x: x[0])


def loader_names() -> list[str]:
    """Registered format names in the order they are tried."""
    return [n for _, n, _, _ in _LOADERS]


def detect_format(path: str | Path) -> str | None:
    """Name of the first loader that recognises ``path`` (``None``: none does)."""
    p = Path(path)
    for _, name, detect, _ in _LOADERS:
        if detect(p):
            return name
    return None


def open_dataset(path: str | Path, fmt: str | None = None, **kwargs) -> StereoSequence:
    """Open any supported stereo dataset; ``fmt`` forces a loader by name; ``kwargs`` go to the loader."""
    p = Path(path)
    if not p.exists():
        raise InputError("dataset not found", p)
    for _, name, detect, opener in _LOADERS:
        if (fmt is None and detect(p)) or fmt == name:
            return opener(p, **kwargs)
    if fmt is not None:
        raise InputError(f"unknown dataset format {fmt!r} (known: {', '.join(loader_names())})", p)
    raise InputError(f"no loader recognises this path{_near_miss(p)} (known formats: {', '.join(loader_names())})", p)


def _near_miss(p: Path) -> str:
    """What a folder that almost has a known layout lacks (``""`` when it resembles none)."""
    if not p.is_dir():
        return ""
    if any((p / d).is_dir() for d in ("image_0", "image_2")) and not (p / "calib.txt").is_file():
        return ": it has KITTI image folders but no calib.txt"
    m = p / "mav0"
    if m.is_dir() and not (m / "cam0" / "data.csv").is_file():
        return ": it has mav0/ (EuRoC) but no mav0/cam0/data.csv"
    if m.is_dir() and not (m / "cam1").is_dir():
        return ": it has mav0/cam0 (EuRoC) but no mav0/cam1 (a stereo pair is needed)"
    if (p / "left").is_dir() != (p / "right").is_dir() or (p / "cam0").is_dir() != (p / "cam1").is_dir():
        return ": it has one camera folder but not the other (left/ + right/ or cam0/ + cam1/)"
    return ""


def construct(cls: type, p: Path, kw: dict) -> StereoSequence:
    """``cls(p, **kw)`` with a one-line ConfigError for options this format does not have."""
    import inspect

    accepted = set(inspect.signature(cls).parameters) - {"root", "path"}
    bad = sorted(set(kw) - accepted)
    if bad:
        raise ConfigError(f"format {cls.name!r} has no option {', '.join(bad)} (it takes: "
                          f"{', '.join(sorted(accepted)) or 'none'})", p)
    return cls(p, **kw)
