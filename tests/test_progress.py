"""The shared progress bar: silent when disabled or when stderr is not a terminal, never changes the items."""

from __future__ import annotations

from seedmap.progress import Progress, track


def test_track_yields_every_item_silently_without_a_terminal(capsys):
    assert list(track(range(5), "test", "item")) == [0, 1, 2, 3, 4]
    assert list(track(iter("abc"), "test", enabled=False)) == ["a", "b", "c"]
    out = capsys.readouterr()
    assert out.out == "" and out.err == ""


def test_progress_methods_are_no_ops_when_disabled(capsys):
    with Progress(3, "test", "job", enabled=False) as bar:
        bar.note("first")
        bar.advance()
        bar.advance(2)
    bar.close()  # closing twice is harmless
    with Progress(2, "test", "job") as bar:  # enabled, but stderr is captured (not a TTY)
        bar.note("x")
        bar.advance()
    out = capsys.readouterr()
    assert out.out == "" and out.err == ""
