"""Other SLAM systems run on seedmap's datasets and scored with seedmap's metrics (``seedmap benchmark``).

:data:`PEERS` is the registry: one entry per peer method, picked once by name. Each peer needs an optional
extra (``seedmap[peers]``); without it the benchmark reports the method as n/a.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable


@dataclass(frozen=True)
class Peer:
    """A peer method: why it is unavailable (``None`` when it runs), how to run it, its benchmark note."""

    name: str
    unavailable: Callable[[], str | None]
    #: ``run(dataset, out, config_dict, slam_cfg, overwrite, progress)`` writes a result folder like ``seedmap slam``
    run: Callable[..., Any]
    note: Callable[[Path], str]
    #: ``check(config_dict)`` raises a one-line :class:`seedmap.errors.InputError` on a bad config (before any run)
    check: Callable[[dict], None]


def _orbslam3_unavailable() -> str | None:
    from seedmap.peers.orbslam3 import unavailable

    return unavailable()


def _orbslam3_run(dataset, out, config: dict, slam_cfg=None, overwrite: bool = False, progress: bool = True):
    from seedmap.peers.orbslam3 import OrbSlam3Config, run_orbslam3

    return run_orbslam3(dataset, Path(out), OrbSlam3Config.model_validate(config or {}), slam_cfg, overwrite,
                        progress)


def _orbslam3_note(run_dir: Path) -> str:
    from seedmap.peers.orbslam3 import peer_note

    return peer_note(run_dir)


def _orbslam3_check(config: dict) -> None:
    from seedmap.peers.orbslam3 import OrbSlam3Config, vocabulary_file

    cfg = OrbSlam3Config.model_validate(config or {})
    if cfg.vocabulary is not None:
        vocabulary_file(cfg)


PEERS: dict[str, Peer] = {
    "orbslam3": Peer("orbslam3", _orbslam3_unavailable, _orbslam3_run, _orbslam3_note, _orbslam3_check),
}

__all__ = ["PEERS", "Peer"]
