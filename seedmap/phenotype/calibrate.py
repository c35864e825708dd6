"""Seed-count calibrations: fit ``log(seeds) = intercept + sum coef_k log(feature_k)`` on counted panicles.

Counted panicles come from a ``panicles.csv`` with a ``seeds_counted`` column filled in by hand for the panicles
that were threshed and counted (empty elsewhere), or from ``seedmap eval phenotype --json`` files of simulated
runs (the true count of every matched panicle). Only panicles of quality ``ok`` are used.
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path
from typing import Sequence

import numpy as np

from seedmap.errors import InputError
from seedmap.phenotype.table import COUNT_FEATURES

#: the hand-counted column of a panicles.csv
COUNTED = "seeds_counted"
#: fewest counted panicles per fitted coefficient (intercept included)
MIN_PER_COEF = 5


def _num(v: object) -> float:
    try:
        x = float(v)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return float("nan")
    return x


def counted_panicles(path: Path) -> list[dict]:
    """Counted ``ok`` panicles of a panicles.csv (``seeds_counted`` filled) or an eval JSON (``per_panicle``)."""
    path = Path(path)
    if not path.is_file():
        raise InputError("file not found", path)
    try:
        if path.suffix.lower() == ".json":
            data = json.loads(path.read_text(encoding="utf-8"))
            rows = [{**r, COUNTED: r["seeds"]} for r in data["per_panicle"]]
        else:
            with open(path, newline="", encoding="utf-8") as f:
                rd = csv.DictReader(f)
                if rd.fieldnames is None or COUNTED not in rd.fieldnames or "quality" not in rd.fieldnames:
                    raise InputError(f"a panicles.csv with a {COUNTED} column filled in for the counted panicles "
                                     "is needed", path)
                rows = list(rd)
    except (ValueError, KeyError, TypeError, UnicodeDecodeError):
        raise InputError("neither a panicles.csv with seeds_counted nor a `seedmap eval phenotype --json` file",
                         path) from None
    return [r for r in rows if r.get("quality") == "ok" and _num(r.get(COUNTED)) > 0]


def fit_calibration(sources: Sequence[Path], features: Sequence[str]) -> dict:
    """Least squares in logs over the counted panicles of ``sources``; ``sigma_log`` is the residual standard
    deviation, ``loo_mape`` the leave-one-out mean absolute percentage error of the count."""
    bad = [f for f in features if f not in COUNT_FEATURES]
    if not features or bad:
        raise InputError(f"features must be some of {', '.join(COUNT_FEATURES)}", Path(sources[0]))
    x, y = [], []
    for p in sources:
        for r in counted_panicles(Path(p)):
            v = [_num(r.get(k)) for k in features]
            if all(q > 0 for q in v):
                x.append([math.log(q) for q in v])
                y.append(math.log(_num(r[COUNTED])))
    need = MIN_PER_COEF * (len(features) + 1)
    if len(x) < need:
        raise InputError(f"{len(x)} counted ok panicles with {', '.join(features)}: at least {need} are needed",
                         Path(sources[0]))
    a = np.c_[np.ones(len(x)), np.asarray(x)]
    yv = np.asarray(y)
    coef, *_ = np.linalg.lstsq(a, yv, rcond=None)
    res = yv - a @ coef
    loo = []
    for k in range(len(yv)):
        keep = np.arange(len(yv)) != k
        ck, *_ = np.linalg.lstsq(a[keep], yv[keep], rcond=None)
        loo.append(abs(math.exp(float(a[k] @ ck - yv[k])) - 1.0))
    return {"kind": "seedmap-phenotype-calibration", "version": 1,
            "model": "log(seeds) = intercept + sum coef[k] * log(k)", "intercept": float(coef[0]),
            "coef": {k: float(c) for k, c in zip(features, coef[1:])},
            "sigma_log": float(res.std(ddof=len(features) + 1)), "panicles": len(x),
            "loo_mape": float(np.mean(loo)), "samples": [Path(p).name for p in sources]}
