"""Every command that writes goes through seedmap.outputs: folders it resumes, single files, full disk, names
checked before the output exists."""

from __future__ import annotations

import json
import resource
import signal
import sys
from pathlib import Path

import pytest

from seedmap.errors import InputError
from seedmap.outputs import (
    MARKER,
    check_output_file,
    check_output_parent,
    is_rerun_recording,
    output_dir,
    read_marker,
    resume_dir,
)


def _run(argv: list, monkeypatch) -> int:
    from seedmap import cli

    monkeypatch.setattr(sys, "argv", ["seedmap", *[str(a) for a in argv]])
    try:
        cli.main()
    except SystemExit as e:
        return 0 if e.code is None else int(e.code)
    return 0


def _mine(tmp_path: Path) -> Path:
    d = tmp_path / "mine"
    d.mkdir()
    (d / "thesis.tex").write_text("years of work\n")
    return d


# ---- folders that commands fill and resume (benchmark, batch, training) -----------------------------------------


def test_resume_dir_marks_a_new_folder_first_and_resumes_its_own_kind(tmp_path):
    out = resume_dir(tmp_path / "b", "benchmark")
    assert read_marker(out)["kind"] == "benchmark"
    (out / "results.csv").write_text("x\n")
    assert resume_dir(out, "benchmark") == out  # resumes
    assert (out / "results.csv").read_text() == "x\n"


def test_resume_dir_refuses_the_users_folder_another_kind_and_inputs(tmp_path):
    m = _mine(tmp_path)
    with pytest.raises(InputError, match="not a folder seedmap wrote"):
        resume_dir(m, "batch")
    assert sorted(p.name for p in m.iterdir()) == ["thesis.tex"]
    resume_dir(m, "training", strict=False)  # training may start in the user's own folder ...
    assert read_marker(m)["kind"] == "training"
    b = resume_dir(tmp_path / "b", "benchmark")
    (b / "results.csv").write_text("x\n")
    with pytest.raises(InputError, match="seedmap benchmark output"):
        resume_dir(b, "training", strict=False)  # ... never in another kind's output
    ds = tmp_path / "ds"
    (ds / "left").mkdir(parents=True)
    for out in (ds, ds / "left", tmp_path):
        with pytest.raises(InputError, match="input"):
            resume_dir(out, "batch", [ds])


# ---- single output files ----------------------------------------------------------------------------------------


def test_rerun_file_is_replaced_only_when_seedmap_recorded_it(tmp_path):
    notes = tmp_path / "notes.txt"
    notes.write_text("mine\n")
    with pytest.raises(InputError, match="--overwrite"):
        check_output_file(notes, overwrite=False, written_by_seedmap=is_rerun_recording)
    with pytest.raises(InputError, match="not written by seedmap"):
        check_output_file(notes, overwrite=True, written_by_seedmap=is_rerun_recording)
    rrd = tmp_path / "run.rrd"
    rrd.write_bytes(b"RRF2" + b"\0" * 16)
    check_output_file(rrd, overwrite=True, written_by_seedmap=is_rerun_recording)
    with pytest.raises(InputError, match="lies inside the input"):
        check_output_file(tmp_path / "ds" / "calib.yaml", [tmp_path / "ds"], overwrite=True)


def test_rerun_over_the_input_calibration_is_refused_before_any_work(tmp_path, monkeypatch, capsys):
    from seedmap.viz.rerun_log import check_rrd_path

    ds = tmp_path / "ds"
    ds.mkdir()
    calib = ds / "calib.yaml"
    calib.write_text("fx: 1\n")
    with pytest.raises(InputError, match="input"):
        check_rrd_path(calib, [ds], overwrite=True)
    assert calib.read_text() == "fx: 1\n"


@pytest.mark.skipif(not Path("/proc/self").is_dir(), reason="needs Linux /proc (a folder nobody can create in)")
def test_an_output_the_file_system_refuses_is_found_before_any_work(tmp_path):
    with pytest.raises(InputError, match="cannot create the output here"):
        check_output_parent(Path("/proc/seedmap-nowhere/out"))


# ---- full disk ------------------------------------------------------------------------------------------------


def test_full_disk_while_writing_is_one_line_and_nothing_is_left(tmp_path):
    from seedmap.io.atomic import atomic_write_bytes

    out = tmp_path / "res"
    old_xfsz = signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    old = resource.getrlimit(resource.RLIMIT_FSIZE)
    try:
        with pytest.raises(InputError) as e:
            with output_dir(out, "slam") as tmp:
                resource.setrlimit(resource.RLIMIT_FSIZE, (4096, old[1]))
                atomic_write_bytes(tmp / "big.bin", b"x" * 100_000)
    finally:
        resource.setrlimit(resource.RLIMIT_FSIZE, old)
        signal.signal(signal.SIGXFSZ, old_xfsz)
    msg = str(e.value)
    assert msg.startswith(str(out)) and "nothing was written" in msg and "\n" not in msg
    assert list(tmp_path.iterdir()) == []


# ---- the command line -------------------------------------------------------------------------------------------


def test_count_never_replaces_the_reconstruction_it_reads(tmp_path, monkeypatch, capsys):
    rec = tmp_path / "rec"
    with output_dir(rec, "reconstruct") as tmp:
        (tmp / "config.yaml").write_text("{}\n")
    before = sorted(p.name for p in rec.iterdir())
    assert _run(["count", rec, "--out", rec, "--overwrite"], monkeypatch) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and str(rec) in err[0]
    assert sorted(p.name for p in rec.iterdir()) == before


def test_batch_refuses_an_unknown_matcher_before_its_output_exists(tmp_path, monkeypatch, capsys):
    field = tmp_path / "field"
    field.mkdir()
    assert _run(["batch", field, "--out", tmp_path / "out", "-q", "--matcher", "nosuch"], monkeypatch) == 2
    err = capsys.readouterr().err
    assert "--matcher" in err and "nosuch" in err
    assert not (tmp_path / "out").exists()


def test_eval_json_over_the_users_file_is_refused(tmp_path, monkeypatch, capsys):
    f = tmp_path / "mine.json"
    f.write_text('{"mine": 1}\n')
    res, ds = tmp_path / "res", tmp_path / "ds"
    res.mkdir()
    ds.mkdir()
    for extra in ([], ["--overwrite"]):
        assert _run(["eval", "slam", res, ds, "--json", f, *extra], monkeypatch) == 2
        assert str(f) in capsys.readouterr().err
    assert json.loads(f.read_text()) == {"mine": 1}
    assert not (res / MARKER).exists()
