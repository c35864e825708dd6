"""Run the ``seedmap`` CLI in-process from a test (shared by the CLI tests)."""

from __future__ import annotations

import sys

import pytest

from seedmap import cli


def run_cli(args: list, monkeypatch) -> int:
    """Exit code of ``seedmap ARGS`` (paths may be Path objects); stdout/stderr go to pytest's capture."""
    monkeypatch.setattr(sys, "argv", ["seedmap", *[str(a) for a in args]])
    with pytest.raises(SystemExit) as e:
        cli.main()
    return int(e.value.code or 0)


def run_cli_ok(args: list) -> None:
    """``seedmap ARGS`` in-process outside a test function (fixtures shared by a module or the whole run); it must exit 0."""
    mp = pytest.MonkeyPatch()
    try:
        code = run_cli(args, mp)
    finally:
        mp.undo()
    assert code == 0, f"seedmap {' '.join(str(a) for a in args)} exited {code}"
