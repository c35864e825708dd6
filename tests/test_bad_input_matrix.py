"""The bad-input matrix: every command, given what a hostile but realistic user gives it, fails cleanly.

For every case (the table is in ``tests/helpers/bad_input*.py``):

* exit code 2 (one case, GT that does not overlap the timestamps, expects a warning and a complete run instead);
* exactly one non-empty stderr line that is not a ``warning: `` line (progress bars aside): it starts with
  ``error: `` and names the offending file or option; no Python warning printed with a source line, no
  ``Traceback`` anywhere;
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
import shutil
import signal
import warnings
from pathlib import Path

import pytest

from helpers.bad_inputs import Assets, Case, all_cases, make_assets, run_main, tree_digest

CASES = all_cases()

#: seconds one case may run before it is reported as hanging
CASE_TIMEOUT_S = 120
#: warning categories a plain ``python`` run does not print (the rest reach the user's terminal)
_HIDDEN_WARNINGS = (DeprecationWarning, PendingDeprecationWarning, ImportWarning, ResourceWarning)
_ANSI = re.compile(r"\x1b\[[0-9;]*[A-Za-z]")
#: a tqdm progress bar ("detect (fast):  50%|#####     | 3/6 [00:01<00:01, 2.9frame/s]"): not a message
_BAR = re.compile(r"[^\r\n|]*\d+%\|[^|\r\n]*\|[^\]\r\n]*\]")
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
    want_error = s.expect == "error"
    if exc is not None:
        problems.append(f"raised {type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}")
    elif code != (2 if want_error else 0):
        problems.append(f"exit code {code}")
    if "Traceback" in stdout or "Traceback" in stderr:
        problems.append("a traceback was printed")
    lines = [ln.strip() for ln in _BAR.sub("\n", stderr.replace("\r", "\n")).splitlines() if ln.strip()]
    errors = [ln for ln in lines if ln.startswith("error: ")]
    stray = [ln for ln in lines if not ln.startswith(("error: ", "warning: "))] + py_warnings
    if stray:
        problems.append(f"{len(stray)} stray stderr line(s): {stray[0][:160]!r}")
    if want_error:
        if len(errors) != 1:
            problems.append(f"{len(errors)} 'error: ' lines")
        if errors and not any(n in errors[0] for n in s.names):
            problems.append(f"the error line names none of {list(s.names)}")
    else:
        if errors:
            problems.append(f"{len(errors)} 'error: ' lines where a warning was expected")
        if not any(n in ln for ln in lines if ln.startswith("warning: ") for n in s.names):
            problems.append(f"no 'warning: ' line naming any of {list(s.names)}")
    lost, written = [], []
    for p in inputs:
        after = tree_digest(p)
        b = before[str(p)]
        if after != b:
            gone = [k for k in b if k not in after]
            changed = [k for k in b if k in after and after[k] != b[k]]
            added = [k for k in after if k not in b]
            what = f"{p.name}: {len(gone)} removed, {len(changed)} changed, {len(added)} added" + (
                f" (e.g. {(gone + changed + added)[0]})" if gone or changed or added else "")
            (lost if gone or changed else written).append(what)
    if lost:
        problems.append("THE USER'S FILES WERE DELETED OR CHANGED: " + "; ".join(lost))
    if written:
        problems.append("files were written into an input: " + "; ".join(written))
    if out is not None:
        if out_existed:
            if tree_digest(out) != out_before:
                problems.append("the existing output was changed")
        elif not want_error and not (out / MARKER).is_file():
            problems.append("the output was not written complete (with its output marker)")
        elif want_error and (out.exists() or out.is_symlink()):
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
            "input_written": bool(written),
            "argv": [str(x).replace(str(tmp_path), "T") for x in s.argv]}


@pytest.mark.parametrize("c", CASES, ids=[c.id for c in CASES])
def test_bad_input(c: Case, assets: Assets, tmp_path: Path, capfd):
    r = check_case(c, assets, tmp_path, capfd)
    log = os.environ.get("SEEDMAP_MATRIX_LOG")
    if log:
        with open(log, "a") as f:
            f.write(json.dumps(r) + "\n")
    if r["ok"]:
        shutil.rmtree(tmp_path, ignore_errors=True)  # ~3 MB of copies per case; kept only when it fails
    assert r["ok"], f"seedmap {' '.join(r['argv'])}\n  " + "\n  ".join(r["problems"]) + f"\n  said: {r['message']}"


# ---- what a killed or interrupted run leaves behind ---------------------------------------------------------------


def test_the_next_run_removes_what_killed_runs_left(assets: Assets, tmp_path: Path, capfd):
    # SIGKILL left hidden `.NAME.*.partial` folders beside the output that no rerun removed
    from helpers.bad_inputs import copy_range

    ds = copy_range(assets, tmp_path)
    out = tmp_path / "res"
    stale = [tmp_path / ".res.99999999.deadbeef.partial", tmp_path / ".res.k2x_9qzt.partial"]  # new and old names
    for p in stale:
        p.mkdir()
        (p / "trajectory.tum").write_text("half written\n")
    before = tree_digest(ds)
    code, exc, _ = _run_limited(["slam", ds, "--out", out, "-q"], None)
    assert exc is None and code == 0, capfd.readouterr().err
    assert (out / "trajectory.tum").is_file()
    assert [p.name for p in stale if p.exists()] == []
    assert tree_digest(ds) == before


def test_ctrl_c_prints_one_line_and_leaves_nothing(assets: Assets, tmp_path: Path, capfd, monkeypatch):
    """Ctrl-C in the middle of a run (delivered while the second frame is registered)."""
    from helpers.bad_inputs import copy_range
    from seedmap.slam.core import SemanticSlam

    ds = copy_range(assets, tmp_path)
    out = tmp_path / "res"
    before = tree_digest(ds)
    calls = []
    real = SemanticSlam.register_frame

    def register_then_ctrl_c(self, *args, **kwargs):  # noqa: ANN001, ANN202
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real(self, *args, **kwargs)

    monkeypatch.setattr(SemanticSlam, "register_frame", register_then_ctrl_c)
    capfd.readouterr()
    code, exc = run_main(["slam", ds, "--out", out, "-q", "--detector", "gt"])
    err = _ANSI.sub("", capfd.readouterr().err)
    assert len(calls) == 2, "the run ended before its second frame"
    assert exc is None, f"raised {exc!r}"
    lines = [ln.strip() for ln in _BAR.sub("\n", err.replace("\r", "\n")).splitlines() if ln.strip()]
    assert len(lines) == 1 and "interrupted" in lines[0], f"exit {code}: {err!r}"
    assert code == 130
    assert not out.exists()
    assert not [p.name for p in tmp_path.iterdir() if p.name.startswith(".res.")]
    assert tree_digest(ds) == before


def _children(pid: int) -> set[int]:
    """Process ids whose parent is ``pid`` (Linux /proc)."""
    out = set()
    for p in Path("/proc").iterdir():
        if p.name.isdigit():
            try:
                stat = (p / "stat").read_text()
            except OSError:
                continue
            if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
                out.add(int(p.name))
    return out


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc/self/stat").is_file(), reason="needs Linux /proc")
@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM], ids=["SIGKILL", "SIGTERM"])
def test_benchmark_workers_die_with_their_parent(assets: Assets, tmp_path: Path, sig):
    # killing `benchmark run --workers 2` left two ~520 MB workers and a resource tracker running for minutes
    import subprocess
    import sys
    import time

    import seedmap
    from helpers.bad_inputs import copy_range

    ds = copy_range(assets, tmp_path)
    argv = ["benchmark", "run", str(ds), "--out", str(tmp_path / "b"), "--workers", "2",
            "--methods", "orb,sift,akaze,seeds+gt,orb,sift"]
    env = {**os.environ, "PYTHONPATH": str(Path(seedmap.__file__).resolve().parents[1])}
    code = f"import sys; from seedmap.cli import main; sys.argv = ['seedmap', *{argv!r}]; main()"
    proc = subprocess.Popen([sys.executable, "-c", code], env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        kids: set[int] = set()
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and proc.poll() is None and len(kids) < 2:
            kids |= _children(proc.pid)
            time.sleep(0.2)
        if proc.poll() is not None:
            pytest.skip("the benchmark finished before its workers were seen")
        time.sleep(1.0)
        kids |= _children(proc.pid)
        proc.send_signal(sig)
        proc.wait(30)
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline and any(_alive(k) for k in kids):
            time.sleep(0.2)
        left = [k for k in kids if _alive(k)]
        assert not left, f"{len(left)} of {len(kids)} child processes still running 20 s after {sig.name}"
    finally:
        for k in _children(proc.pid) | kids:
            try:
                os.kill(k, signal.SIGKILL)
            except OSError:
                pass
        if proc.poll() is None:
            proc.kill()
