"""Text in seedmap's matplotlib figures: any dataset or method name draws, without warnings.

A dataset named ``高粱_range`` made matplotlib print one "Glyph ... missing from font(s) DejaVu Sans" warning per
character and figure, and a name with ``$`` in it was parsed as maths. Build and save figures inside
:func:`figure_text`.
"""

from __future__ import annotations

import warnings
from contextlib import contextmanager
from typing import Iterator

__all__ = ["FALLBACK_FONTS", "figure_text"]

#: fonts tried in order for characters the default font lacks (CJK names), where installed; the last one ships
#: with matplotlib >= 3.10 and draws a placeholder box for any character
FALLBACK_FONTS = ("Noto Sans CJK JP", "Noto Sans CJK SC", "Source Han Sans SC", "WenQuanYi Zen Hei",
                  "Droid Sans Fallback", "Microsoft YaHei", "PingFang SC", "Hiragino Sans", "Arial Unicode MS",
                  "Last Resort High-Efficiency")


@contextmanager
def figure_text() -> Iterator[None]:
    """Within: text is plain (a ``$`` in a name is not maths), characters the default font lacks come from the
    installed :data:`FALLBACK_FONTS`, and one that no font has is drawn as a box without a warning."""
    import matplotlib
    from matplotlib import font_manager

    installed = {f.name for f in font_manager.fontManager.ttflist}
    family = [*matplotlib.rcParams["font.family"], *(f for f in FALLBACK_FONTS if f in installed)]
    with matplotlib.rc_context({"font.family": family, "text.parse_math": False}), warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Glyph .* missing from font")
        yield
