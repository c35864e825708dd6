"""The one output policy: --overwrite replaces only seedmap's own output of the same kind, never an input."""

from __future__ import annotations

import errno
import hashlib
import os
import subprocess
import sys
from pathlib import Path

import pytest

from seedmap.errors import InputError
from seedmap.outputs import (
    MARKER,
    check_output_file,
    clean_stale_partials,
    is_rerun_recording,
    output_dir,
    output_kind,
    read_marker,
)


def _tree_digest(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


def _write(tmp: Path, name: str = "a.txt", text: str = "new") -> None:
    (tmp / name).write_text(text)


def test_new_folder_is_written_with_its_marker(tmp_path):
    out = tmp_path / "res"
    with output_dir(out, "slam") as tmp:
        _write(tmp)
    assert (out / "a.txt").read_text() == "new"
    assert read_marker(out)["kind"] == "slam"
    assert output_kind(out) == "slam"
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_existing_result_needs_overwrite_then_is_replaced(tmp_path):
    out = tmp_path / "res"
    with output_dir(out, "slam") as tmp:
        _write(tmp, text="old")
    with pytest.raises(InputError, match="--overwrite"):
        with output_dir(out, "slam") as tmp:
            _write(tmp)
    assert (out / "a.txt").read_text() == "old"
    with output_dir(out, "slam", overwrite=True) as tmp:
        _write(tmp, text="new")
    assert (out / "a.txt").read_text() == "new"


def test_overwrite_never_replaces_a_folder_seedmap_did_not_write(tmp_path):
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "thesis.tex").write_text("years of work")
    before = _tree_digest(mine)
    with pytest.raises(InputError, match="not a folder seedmap wrote"):
        with output_dir(mine, "slam", overwrite=True) as tmp:
            _write(tmp)
    assert _tree_digest(mine) == before


def test_overwrite_never_replaces_another_kind_of_output(tmp_path):
    out = tmp_path / "rec"
    with output_dir(out, "reconstruct") as tmp:
        _write(tmp, text="cloud")
    with pytest.raises(InputError, match="reconstruct output, not a count result"):
        with output_dir(out, "count", overwrite=True) as tmp:
            _write(tmp)
    assert (out / "a.txt").read_text() == "cloud"


@pytest.mark.parametrize("where", ["same", "inside", "contains"])
def test_an_input_is_never_an_output(tmp_path, where):
    data = tmp_path / "P" / "r1"
    (data / "left").mkdir(parents=True)
    (data / "left" / "000000.png").write_bytes(b"png")
    out = {"same": data, "inside": data / "left", "contains": tmp_path / "P"}[where]
    before = _tree_digest(tmp_path)
    with pytest.raises(InputError, match="input"):
        with output_dir(out, "slam", inputs=[data], overwrite=True) as tmp:
            _write(tmp)
    assert _tree_digest(tmp_path) == before


def test_a_recorded_dataset_is_never_replaced(tmp_path):
    data = tmp_path / "rec"
    for side in ("left", "right"):
        (data / side).mkdir(parents=True)
        (data / side / "000000.png").write_bytes(b"png")
    before = _tree_digest(data)
    with pytest.raises(InputError):
        with output_dir(data, "slam", overwrite=True) as tmp:
            _write(tmp)
    assert _tree_digest(data) == before


def test_an_error_leaves_the_old_result_and_no_partial(tmp_path):
    out = tmp_path / "res"
    with output_dir(out, "detect") as tmp:
        _write(tmp, text="old")
    with pytest.raises(RuntimeError):
        with output_dir(out, "detect", overwrite=True) as tmp:
            _write(tmp, text="half")
            raise RuntimeError("boom")
    assert (out / "a.txt").read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["res"]


def test_full_disk_is_one_line_and_nothing_is_half_written(tmp_path, monkeypatch):
    out = tmp_path / "res"
    real_replace = os.replace

    def full(src, dst):
        if str(dst) == str(out):
            raise OSError(errno.ENOSPC, "No space left on device")
        return real_replace(src, dst)

    monkeypatch.setattr(os, "replace", full)
    with pytest.raises(InputError, match="no space left") as e:
        with output_dir(out, "slam") as tmp:
            _write(tmp)
    assert "\n" not in str(e.value) and str(out) in str(e.value)
    assert not out.exists()
    assert list(tmp_path.iterdir()) == []


def test_leftovers_of_a_killed_run_are_removed_by_the_next_run(tmp_path):
    out = tmp_path / "res"
    code = (f"import os, sys; from pathlib import Path; from seedmap.outputs import output_dir\n"
            f"with output_dir(Path({str(out)!r}), 'slam') as t:\n"
            f"    (t / 'a.txt').write_text('x'); os._exit(9)\n")
    subprocess.run([sys.executable, "-c", code], check=False)
    left = [p for p in tmp_path.iterdir() if p.name.endswith(".partial")]
    assert len(left) == 1 and not out.exists()
    live = tmp_path / f".res.{os.getpid()}.0123abcd.partial"
    live.mkdir()
    removed = clean_stale_partials(out)
    assert removed == left
    assert live.is_dir(), "a partial folder of a running process is kept"
    with output_dir(out, "slam") as tmp:
        _write(tmp)
    assert (out / MARKER).is_file()


def test_results_of_older_versions_are_recognised_by_their_files(tmp_path):
    old = tmp_path / "old"
    old.mkdir()
    for f in ("config.yaml", "metrics.json", "trajectory.tum"):
        (old / f).write_text("x")
    assert output_kind(old) == "slam"
    with output_dir(old, "slam", overwrite=True) as tmp:
        _write(tmp)
    assert read_marker(old)["kind"] == "slam"
    (tmp_path / "half").mkdir()
    (tmp_path / "half" / "metrics.json").write_text("{}")
    assert output_kind(tmp_path / "half") is None


def test_output_file_policy(tmp_path):
    rec = tmp_path / "run.rrd"
    rec.write_bytes(b"RRF2" + b"\0" * 16)
    assert is_rerun_recording(rec)
    with pytest.raises(InputError, match="--overwrite"):
        check_output_file(rec, written_by_seedmap=is_rerun_recording)
    check_output_file(rec, overwrite=True, written_by_seedmap=is_rerun_recording)
    calib = tmp_path / "calib.yaml"
    calib.write_text("fx: 1\n")
    with pytest.raises(InputError, match="not written by seedmap"):
        check_output_file(calib, overwrite=True, written_by_seedmap=is_rerun_recording)
    with pytest.raises(InputError, match="input"):
        check_output_file(calib, inputs=[tmp_path], overwrite=True, written_by_seedmap=lambda p: True)
    assert calib.read_text() == "fx: 1\n"
