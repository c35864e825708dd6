"""The provenance a benchmark JSON written from a result folder carries: command, commit, date, machine."""

from __future__ import annotations

import datetime
import os
import platform
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def stamp(command: str) -> dict:
    """``{"command", "commit", "date", "machine"}`` for the JSON of a result written by ``command``."""
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True,
                            text=True).stdout.strip() or "unknown"
    return {"command": command, "commit": commit, "date": datetime.date.today().isoformat(),
            "machine": f"{os.cpu_count()} CPUs, {platform.machine()}"}
