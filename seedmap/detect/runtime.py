"""Loading seedmap's ONNX files (the fast CNN and its refiner) into onnxruntime."""

from __future__ import annotations

import json
from pathlib import Path

from seedmap.errors import InputError

#: the shipped weights folder
WEIGHTS_DIR = Path(__file__).with_name("weights")


def shipped_or_path(name: str | Path) -> Path:
    """``name`` as a path, unless it is a bare file name that is no file in the working directory but one of the
    files shipped in ``seedmap/detect/weights/`` (then that one)."""
    p = Path(name)
    if p.parent == Path(".") and not p.is_file():
        shipped = WEIGHTS_DIR / p.name
        if shipped.is_file():
            return shipped
    return p


def load_session(path: str | Path, threads: int = 0, kind: str = "fast_cnn"):  # noqa: ANN201 - ort.InferenceSession
    """An onnxruntime InferenceSession of a seedmap ONNX file whose metadata says ``kind`` (``fast_cnn``: the network;
    ``cnn_refiner``: its second stage); a one-line :class:`InputError` otherwise. ``threads`` 0 = onnxruntime's
    default."""
    import onnxruntime as ort

    p = Path(path)
    if not p.is_file():
        raise InputError(f"{'fast CNN' if kind == 'fast_cnn' else kind.replace('_', ' ')} weights not found", p)
    so = ort.SessionOptions()
    if threads > 0:
        so.intra_op_num_threads = int(threads)
        so.inter_op_num_threads = 1
    so.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    try:
        sess = ort.InferenceSession(str(p), so, providers=["CPUExecutionProvider"])
    except Exception as e:  # onnxruntime raises its own exception types for bad files
        raise InputError(f"not a readable ONNX model ({str(e).splitlines()[0][:120]})", p) from None
    meta = sess.get_modelmeta().custom_metadata_map
    if meta.get("seedmap_kind") != kind:
        raise InputError(f"holds {meta.get('seedmap_kind') or 'unknown'} weights, expected {kind}", p)
    return sess


def network_info(path: str | Path) -> dict:
    """The ``info`` metadata of a seedmap fast_cnn ONNX file (what training recorded; ``{}`` when it has none or it
    is not a JSON object)."""
    meta = load_session(path, 1).get_modelmeta().custom_metadata_map
    try:
        info = json.loads(meta.get("info", "{}"))
    except ValueError:
        return {}
    return info if isinstance(info, dict) else {}
