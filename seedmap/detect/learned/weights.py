"""Weights as safetensors with their architecture config in the metadata (never pickles).

A weights file holds the model's ``state_dict`` tensors plus string metadata:
``seedmap_kind`` (``detector`` | ``segmenter``), ``arch`` (JSON of the architecture config), and
free ``info`` (JSON: training step, metrics). A training checkpoint additionally holds the
optimiser state (tensors under ``optim.<model>.<param index>.<name>``, the rest as JSON in the
metadata), so ``--resume`` continues exactly.
"""

from __future__ import annotations

import json
from pathlib import Path

import torch
from safetensors import SafetensorError
from safetensors.torch import load_file, save_file
from torch import nn

from seedmap.errors import InputError
from seedmap.io.atomic import atomic_write_bytes


def save_weights(path: Path, kind: str, arch: dict, tensors: dict[str, torch.Tensor], info: dict | None = None,
                 extra_meta: dict[str, str] | None = None) -> None:
    """Atomically write ``tensors`` + metadata to ``path``."""
    from safetensors.torch import save

    meta = {"seedmap_kind": kind, "arch": json.dumps(arch), "info": json.dumps(info or {})}
    meta.update(extra_meta or {})
    t = {k: v.detach().contiguous().cpu() for k, v in tensors.items()}
    atomic_write_bytes(Path(path), save(t, metadata=meta))


def read_weights(path: str | Path, kind: str | None = None) -> tuple[dict[str, torch.Tensor], dict[str, str]]:
    """``(tensors, metadata)``; a one-line InputError for a missing, corrupt or wrong-kind file."""
    p = Path(path)
    if not p.is_file():
        raise InputError("weights file not found", p)
    try:
        from safetensors import safe_open

        with safe_open(str(p), framework="pt") as f:
            meta = dict(f.metadata() or {})
        tensors = load_file(str(p))
    except (SafetensorError, OSError, ValueError, RuntimeError) as e:
        raise InputError(f"not a readable safetensors weights file ({str(e).splitlines()[0][:120]})", p) from None
    if kind is not None and meta.get("seedmap_kind") != kind:
        raise InputError(f"holds {meta.get('seedmap_kind') or 'unknown'} weights, expected {kind} weights", p)
    return tensors, meta


def load_into(model: nn.Module, tensors: dict[str, torch.Tensor], path: str | Path, prefix: str = "") -> None:
    """Load ``tensors`` (keys under ``prefix``) into ``model``; a clear error if they do not fit."""
    sd = {k[len(prefix):]: v for k, v in tensors.items() if k.startswith(prefix)}
    own = model.state_dict()
    missing = [k for k in own if k not in sd]
    unexpected = [k for k in sd if k not in own]
    bad = [k for k in own if k in sd and tuple(sd[k].shape) != tuple(own[k].shape)]
    if missing or unexpected or bad:
        what = []
        if missing:
            what.append(f"{len(missing)} missing (e.g. {missing[0]})")
        if unexpected:
            what.append(f"{len(unexpected)} unexpected (e.g. {unexpected[0]})")
        if bad:
            k = bad[0]
            what.append(f"{len(bad)} of wrong shape (e.g. {k}: file {tuple(sd[k].shape)} vs model {tuple(own[k].shape)})")
        raise InputError("weights do not match the architecture: " + ", ".join(what), path)
    model.load_state_dict(sd, strict=True)


def optimizer_tensors(opt: torch.optim.Optimizer, prefix: str) -> tuple[dict[str, torch.Tensor], str]:
    """Split an optimiser state into tensors and a JSON string of everything else."""
    sd = opt.state_dict()
    tensors: dict[str, torch.Tensor] = {}
    scalars: dict[str, dict] = {}
    for pid, st in sd["state"].items():
        for name, v in st.items():
            if torch.is_tensor(v):
                tensors[f"{prefix}.{pid}.{name}"] = v
            else:
                scalars.setdefault(str(pid), {})[name] = v
    return tensors, json.dumps({"param_groups": sd["param_groups"], "scalars": scalars})


def restore_optimizer(opt: torch.optim.Optimizer, tensors: dict[str, torch.Tensor], meta_json: str,
                      prefix: str) -> None:
    meta = json.loads(meta_json)
    state: dict[int, dict] = {}
    for k, v in tensors.items():
        if k.startswith(prefix + "."):
            pid, name = k[len(prefix) + 1:].split(".", 1)
            state.setdefault(int(pid), {})[name] = v
    for pid, d in meta["scalars"].items():
        state.setdefault(int(pid), {}).update(d)
    opt.load_state_dict({"state": state, "param_groups": meta["param_groups"]})


__all__ = ["load_into", "optimizer_tensors", "read_weights", "restore_optimizer", "save_file", "save_weights"]
