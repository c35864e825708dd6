"""What a command prints on stderr besides its result: ``warning: <message>`` lines, nothing from the libraries.

Python warnings and seedmap's own warnings print as one line without a source file; a damaged PNG is refused
without libpng's own ``libpng error: ...`` line; figures draw any dataset name (CJK, ``$``) without glyph warnings.
"""

from __future__ import annotations

import logging
import warnings

import cv2
import numpy as np
import pytest

from seedmap.errors import InputError
from seedmap.io.images import imdecode_quiet, png_is_whole, read_label_png, read_rgb
from seedmap.log import cli_messages, warn


def test_python_and_seedmap_warnings_print_one_line_each(capsys):
    old = warnings.showwarning
    with cli_messages(), warnings.catch_warnings():
        warnings.simplefilter("always")
        warnings.warn("a glyph is\nmissing", UserWarning)
        warnings.warn("invalid value", RuntimeWarning)
        warn("the views are 120.0 deg apart")
        warn("the views are 120.0 deg apart")  # once per command
        logging.getLogger("seedmap.io").warning("ds: grayscale images converted")
    assert warnings.showwarning is old
    err = capsys.readouterr().err
    assert err.splitlines() == ["warning: a glyph is missing", "warning: invalid value",
                                "warning: the views are 120.0 deg apart", "warning: ds: grayscale images converted"]
    warn("outside a command")  # library use: Python logging, not the command line's handler
    assert "warning: outside" not in capsys.readouterr().err


def _png(h: int = 60, w: int = 80) -> bytes:
    img = np.random.default_rng(0).integers(0, 256, (h, w, 3), dtype=np.uint8)
    return cv2.imencode(".png", img)[1].tobytes()


def _damaged() -> dict[str, bytes]:
    b = _png()
    crc = bytearray(b)
    crc[len(b) // 2] ^= 0xFF
    tail = bytearray(b)
    tail[-20] ^= 0xFF  # the zlib check value of the last IDAT chunk
    return {"truncated": b[: len(b) // 3], "no-iend": b[:-12], "bit-flip": bytes(crc), "bit-flip-tail": bytes(tail),
            "garbage": b"\x89PNG\r\n\x1a\n" + b"garbage" * 100, "signature-only": b[:8]}


@pytest.mark.parametrize("kind", list(_damaged()))
def test_damaged_png_is_refused_without_libpng_output(kind, tmp_path, capfd):
    p = tmp_path / "000001.png"
    p.write_bytes(_damaged()[kind])
    capfd.readouterr()
    with pytest.raises(InputError, match="000001.png"):
        read_rgb(p)
    with pytest.raises(InputError, match="000001.png"):
        read_label_png(p)
    assert capfd.readouterr().err == ""


def test_whole_png_decodes_as_before():
    b = _png()
    assert png_is_whole(b) and png_is_whole(np.frombuffer(b, np.uint8))
    assert np.array_equal(imdecode_quiet(np.frombuffer(b, np.uint8)), cv2.imdecode(np.frombuffer(b, np.uint8), -1))
    jpg = cv2.imencode(".jpg", np.zeros((8, 8, 3), np.uint8))[1]
    assert png_is_whole(jpg) and imdecode_quiet(jpg) is not None  # not a PNG: left to the decoder


def test_figures_draw_cjk_and_dollar_names_without_warnings():
    from seedmap.eval.benchmark.report import bar_chart_png, matches_plot_png
    from seedmap.eval.benchmark.spec import RunRecord

    recs = [RunRecord("user", "高粱_range $1", m, "ok", mdm_fraction=0.5, stereo_matches=[10, 12],
                      temporal_matches=[8, 9], inlier_matches=[7, 8]) for m in ("orb", "种子$")]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert bar_chart_png(recs)[:4] == b"\x89PNG"
        assert matches_plot_png(recs, "user", "高粱_range $1")[:4] == b"\x89PNG"
    assert [str(w.message) for w in caught] == []
