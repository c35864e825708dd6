"""The bad-input matrix: every command, given what a hostile but realistic user gives it, fails cleanly.

For every case (the table is in ``tests/helpers/bad_inputs.py``):

* exit code 2;
* exactly one non-empty stderr line that is not a ``warning: `` line, it starts with ``error: `` and names the
  offending file or option; no Python warning printed with a source line, no ``Traceback`` anywhere;
* every input (files and folders the user gave, a pre-existing output folder included) byte-identical;
* the output absent (or, where it existed, unchanged; a benchmark/batch record of failed runs may be written
  complete, with its output marker); no ``.partial`` leftovers beside it; no YAML tag ever executed.

The ``data-loss`` group is the one that matters most: ``--overwrite``, ``--rerun FILE``, ``--json``/``--out FILE``
and ``batch --out`` pointed at the user's own files or at the command's inputs.

``SEEDMAP_MATRIX_LOG=FILE`` appends one JSON line per case (what happened) for the failure report.
"""

from __future__ import annotations

import json
import os
import re
import resource
import signal
import warnings
from pathlib import Path

import pytest

from helpers.bad_inputs import CASES, Assets, Case, make_assets, run_main, tree_digest

#: seconds one case may run before it is reported as hanging
CASE_TIMEOUT_S = 120
#: warning categories a plain ``python`` run does not print (the rest reach the user's terminal)
_HIDDEN_WARNINGS = (DeprecationWarning, PendingDeprecationWarning, ImportWarning, ResourceWarning)
_ANSI = re.compile(r"\x1b\[[0-9;]*[A-Za-z]")
#: name of the marker file in every folder seedmap writes (seedmap.outputs.MARKER)
MARKER = ".seedmap-output.json"


@pytest.fixture(scope="module")
def assets(tmp_path_factory) -> Assets:
    return make_assets(tmp_path_factory.mktemp("matrix_assets"))


def test_the_matrix_is_large_and_ids_are_unique():
    ids = [c.id for c in CASES]
    assert len(ids) == len(set(ids)), sorted({i for i in ids if ids.count(i) > 1})
    assert len(CASES) >= 150
    groups = {c.group for c in CASES}
    assert {"data-loss", "dataset", "config", "output", "bag", "weights", "counts", "training"} <= groups


class _Timeout(Exception):
    pass


def _on_alarm(signum, frame):  # noqa: ANN001
    raise _Timeout(f"case ran longer than {CASE_TIMEOUT_S} s")


def _run_limited(argv: list, fsize: int | None) -> tuple[int | None, BaseException | None, list[str]]:
    """Run ``seedmap ARGV`` with a time limit (and a file size limit: a "full disk"); Python warnings it printed."""
    old_alarm = signal.signal(signal.SIGALRM, _on_alarm)
    old_xfsz = signal.signal(signal.SIGXFSZ, signal.SIG_IGN) if fsize else None
    old_lim = resource.getrlimit(resource.RLIMIT_FSIZE)
    signal.alarm(CASE_TIMEOUT_S)
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            if fsize:
                resource.setrlimit(resource.RLIMIT_FSIZE, (fsize, old_lim[1]))
            try:
                code, exc = run_main(argv)
            finally:
                if fsize:
                    resource.setrlimit(resource.RLIMIT_FSIZE, old_lim)
    except _Timeout as e:
        code, exc, caught = None, e, []
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old_alarm)
        if old_xfsz is not None:
            signal.signal(signal.SIGXFSZ, old_xfsz)
    shown = [f"{w.filename}:{w.lineno}: {w.category.__name__}: {w.message}" for w in caught
             if not issubclass(w.category, _HIDDEN_WARNINGS)]
    return code, exc, shown


def _leftovers(out: Path, before: set[str]) -> list[str]:
    parent = out.parent
    if not parent.is_dir():
        return []
    try:
        names = {p.name for p in parent.iterdir()}
    except OSError:
        return []
    return sorted(n for n in names - before if n.startswith(f".{out.name}.") or n.endswith(".partial"))


def check_case(c: Case, assets: Assets, tmp_path: Path, capfd) -> dict:
    """Run one case; the dict says what went wrong (``problems``) and what happened."""
    s = c.build(assets, tmp_path)
    inputs = [Path(p) for p in s.inputs]
    before = {str(p): tree_digest(p) for p in inputs}
    out = Path(s.out) if s.out is not None else None
    out_existed = out is not None and (out.exists() or out.is_symlink())
    out_before = tree_digest(out) if out_existed else {}
    siblings = set()
    if out is not None and out.parent.is_dir():
        try:
            siblings = {p.name for p in out.parent.iterdir()}
        except OSError:
            pass
    capfd.readouterr()
    code, exc, py_warnings = _run_limited(s.argv, s.fsize)
    cap = capfd.readouterr()
    stdout, stderr = _ANSI.sub("", cap.out), _ANSI.sub("", cap.err)
    problems: list[str] = []
    if exc is not None:
        problems.append(f"raised {type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}")
    elif code != 2:
        problems.append(f"exit code {code}")
    if "Traceback" in stdout or "Traceback" in stderr:
        problems.append("a traceback was printed")
    lines = [ln.strip() for ln in stderr.splitlines() if ln.strip()]
    errors = [ln for ln in lines if ln.startswith("error: ")]
    stray = [ln for ln in lines if not ln.startswith(("error: ", "warning: "))] + py_warnings
    if len(errors) != 1:
        problems.append(f"{len(errors)} 'error: ' lines")
    if stray:
        problems.append(f"{len(stray)} stray stderr line(s): {stray[0][:160]!r}")
    if errors and not any(n in errors[0] for n in s.names):
        problems.append(f"the error line names none of {list(s.names)}")
    lost = []
    for p in inputs:
        after = tree_digest(p)
        b = before[str(p)]
        if after != b:
            gone = [k for k in b if k not in after]
            changed = [k for k in b if k in after and after[k] != b[k]]
            added = [k for k in after if k not in b]
            lost.append(f"{p.name}: {len(gone)} removed, {len(changed)} changed, {len(added)} added"
                        + (f" (e.g. {(gone + changed + added)[0]})" if gone or changed or added else ""))
    if lost:
        problems.append("INPUT CHANGED: " + "; ".join(lost))
    if out is not None:
        if out_existed:
            if tree_digest(out) != out_before:
                problems.append("the existing output was changed")
        elif out.exists() or out.is_symlink():
            if not s.record_ok:
                problems.append("an output was written")
            elif not (out / MARKER).is_file():
                problems.append("the record of failed runs carries no output marker (complete?)")
        left = _leftovers(out, siblings)
        if left:
            problems.append(f"left behind {left[:3]}")
    if s.canary is not None and s.canary.exists():
        problems.append("A YAML TAG RAN CODE")
    first_err = errors[0] if errors else ""
    tb = [ln for ln in (stderr + stdout).splitlines() if ln.strip()]
    head = first_err or (f"{type(exc).__name__}: {exc}" if exc else "") or next(
        (ln for ln in reversed(tb) if "Error" in ln or "error" in ln), tb[-1] if tb else "")
    return {"id": c.id, "group": c.group, "ok": not problems, "problems": problems, "exit": code,
            "message": head[:300], "stray": stray[:3], "data_lost": bool(lost),
            "argv": [str(x).replace(str(tmp_path), "T") for x in s.argv]}


@pytest.mark.parametrize("c", CASES, ids=[c.id for c in CASES])
def test_bad_input(c: Case, assets: Assets, tmp_path: Path, capfd):
    r = check_case(c, assets, tmp_path, capfd)
    log = os.environ.get("SEEDMAP_MATRIX_LOG")
    if log:
        with open(log, "a") as f:
            f.write(json.dumps(r) + "\n")
    assert r["ok"], f"seedmap {' '.join(r['argv'])}\n  " + "\n  ".join(r["problems"]) + f"\n  said: {r['message']}"
