"""A small multilayer perceptron in numpy (``x @ w + b``, ReLU between), its weights file and its ONNX graph.

The fast CNN's refiner (:mod:`seedmap.detect.cnn_refine`) is one; training is in :mod:`seedmap.detect.train_refiner`.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from seedmap.detect.kernels import PATCH_LUT, gather_patches
from seedmap.errors import InputError

#: the weights kind this project writes (checked on load)
KIND = "cnn_refiner"


def patches(img: np.ndarray, x: np.ndarray, y: np.ndarray, r: int, extra: int = 0) -> np.ndarray:
    """``(N, (2r+1)^2 * channels + extra)`` float32: the square of half size ``r`` around each pixel ``x``, ``y``
    (N,) int (inside the image) of the uint8 ``img`` (H, W) or (H, W, C), / 255, zero outside the image; row-major,
    the channels of a pixel together; ``extra`` columns left for the caller (uninitialised). One compiled gather
    (:func:`seedmap.detect.kernels.gather_patches`)."""
    img = np.ascontiguousarray(img)
    im3 = img.reshape(img.shape[0], img.shape[1], -1)
    ch = im3.shape[2]
    n = len(x)
    out = np.empty((n, (2 * r + 1) ** 2 * ch + int(extra)), np.float32)
    gather_patches(im3, np.ascontiguousarray(x, np.int64), np.ascontiguousarray(y, np.int64), int(r), PATCH_LUT, out)
    return out


@dataclass
class Mlp:
    """MLP weights (``w0 b0 w1 b1 ...``), the patch radius of its inputs, free-form ``info`` and its ``kind``."""

    layers: list[tuple[np.ndarray, np.ndarray]]
    patch_r: int
    info: dict | None = None
    kind: str = KIND

    def forward(self, x: np.ndarray) -> np.ndarray:
        """The MLP's output for the rows of ``x`` (float32)."""
        # cv2.gemm, not numpy's BLAS: a multi-threaded BLAS spins its threads on this small product
        x = np.ascontiguousarray(x, np.float32)
        for k, (w, b) in enumerate(self.layers):
            x = cv2.gemm(x, w, 1.0, None, 0.0) + b if len(x) else np.zeros((0, w.shape[1]), np.float32)
            if k < len(self.layers) - 1:
                np.maximum(x, 0.0, out=x)
        return x

    def save(self, path: str | Path) -> Path:
        """Write the weights as ``.safetensors`` (kind, patch radius and info as metadata), atomically."""
        from safetensors.numpy import save

        from seedmap.io.atomic import atomic_write_bytes

        t = {}
        for k, (w, b) in enumerate(self.layers):
            t[f"w{k}"] = np.ascontiguousarray(w, np.float32)
            t[f"b{k}"] = np.ascontiguousarray(b, np.float32)
        meta = {"seedmap_kind": self.kind, "patch_r": str(self.patch_r), "info": json.dumps(self.info or {})}
        atomic_write_bytes(Path(path), save(t, metadata=meta))
        return Path(path)

    @classmethod
    def load(cls, path: str | Path, kind: str = KIND, patch_r: int = 0) -> Mlp:
        """Weights written by :meth:`save`; a one-line :class:`InputError` for another kind or broken layers."""
        from seedmap.io.tensors import read_safetensors

        p = Path(path)
        if not p.is_file():
            raise InputError(f"{kind.replace('_', ' ')} weights not found", p)
        t, meta = read_safetensors(p)
        if meta.get("seedmap_kind") != kind:
            raise InputError(f"holds {meta.get('seedmap_kind') or 'unknown'} weights, expected {kind}", p)
        n = len([k for k in t if k.startswith("w")])
        if n == 0 or any(f"b{k}" not in t for k in range(n)):
            raise InputError(f"{kind} weights lack their layers (w0, b0, ...)", p)
        layers = [(t[f"w{k}"].astype(np.float32), t[f"b{k}"].astype(np.float32)) for k in range(n)]
        for k in range(n):
            w, b = layers[k]
            if w.ndim != 2 or b.shape != (w.shape[1],) or (k and w.shape[0] != layers[k - 1][0].shape[1]):
                raise InputError(f"{kind} layer {k} has shape {w.shape} / {b.shape}, which does not chain", p)
        return cls(layers, int(meta.get("patch_r", patch_r)), json.loads(meta.get("info", "{}")), kind)

    def onnx_bytes(self) -> bytes:
        """The MLP as an ONNX graph (MatMul + Add, ReLU between; input ``features`` (N, D), output ``out``) with
        its kind, patch radius and info as metadata. Needs the ``onnx`` package (the learned extra)."""
        import onnx
        from onnx import TensorProto, helper, numpy_helper

        nodes, inits = [], []
        cur = "features"
        for k, (w, b) in enumerate(self.layers):
            inits += [numpy_helper.from_array(np.asarray(w, np.float32), f"w{k}"),
                      numpy_helper.from_array(np.asarray(b, np.float32), f"b{k}")]
            last = k == len(self.layers) - 1
            nodes += [helper.make_node("MatMul", [cur, f"w{k}"], [f"m{k}"]),
                      helper.make_node("Add", [f"m{k}", f"b{k}"], ["out" if last else f"a{k}"])]
            if not last:
                nodes.append(helper.make_node("Relu", [f"a{k}"], [f"h{k}"]))
                cur = f"h{k}"
        d_in, d_out = self.layers[0][0].shape[0], self.layers[-1][0].shape[1]
        graph = helper.make_graph(nodes, self.kind,
                                  [helper.make_tensor_value_info("features", TensorProto.FLOAT, ["n", d_in])],
                                  [helper.make_tensor_value_info("out", TensorProto.FLOAT, ["n", d_out])], inits)
        model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
        model.ir_version = 8
        for k, v in {"seedmap_kind": self.kind, "patch_r": str(self.patch_r),
                     "info": json.dumps(self.info or {})}.items():
            e = model.metadata_props.add()
            e.key, e.value = k, v
        onnx.checker.check_model(model)
        return model.SerializeToString()
