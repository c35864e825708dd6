"""``seedmap config show``: the configuration a command runs with, as YAML with one comment line per field.

The output is a valid ``--config`` file: ``seedmap config show slam > my.yaml``, edit, ``seedmap slam DATA
--config my.yaml``. Field comments come from ``Field(description=...)``, else from the ``#:`` comment above
the field (or a trailing ``# ...`` on its line) in the config class's source.
"""

from __future__ import annotations

import ast
import importlib
import inspect
import io
import re
import textwrap
import tokenize
from functools import lru_cache
from pathlib import Path
from typing import Any, List, Optional

import typer
import yaml
from pydantic import BaseModel

from seedmap.cli.app import ConfigOpt, SetOpt, config_app
from seedmap.errors import SeedmapError

#: config kind -> (module, class, the commands that read it with --config)
KINDS: dict[str, tuple[str, str, str]] = {
    "slam": ("seedmap.slam.config", "SlamConfig", "seedmap slam, batch, eval associate"),
    "phenotype": ("seedmap.phenotype.config", "PhenotypeConfig", "seedmap phenotype, eval phenotype"),
    "detect": ("seedmap.detect.run", "DetectRunConfig", "seedmap detect"),
    "reconstruct": ("seedmap.recon.config", "ReconConfig", "seedmap reconstruct, count"),
    "simulate-range": ("seedmap.sim.config", "SimConfig", "seedmap simulate range"),
    "simulate-panicle": ("seedmap.sim.panicle_scan", "PanicleScanConfig", "seedmap simulate panicle"),
    "benchmark": ("seedmap.eval.benchmark", "BenchmarkConfig", "seedmap benchmark paper, run, tune"),
    "sweep": ("seedmap.eval.benchmark.sweep", "SweepConfig", "seedmap benchmark sweep"),
    "train-detector": ("seedmap.detect.learned.train", "DetectorTrainConfig", "seedmap train detector"),
    "train-segmenter": ("seedmap.detect.learned.train", "SegmenterTrainConfig", "seedmap train segmenter"),
}
#: other names a user may type for a kind (the command's name, or a short form)
ALIASES = {"batch": "slam", "recon": "reconstruct", "count": "reconstruct", "sim": "simulate-range",
           "simulate": "simulate-range", "range": "simulate-range", "panicle": "simulate-panicle"}
_TORCH_KINDS = {"train-detector", "train-segmenter"}


def config_class(kind: str) -> tuple[str, type[BaseModel]]:
    """The canonical kind name and the config class of ``kind`` (a kind, or an alias of one)."""
    name = ALIASES.get(kind.lower(), kind.lower())
    if name not in KINDS:
        raise SeedmapError(f"unknown config {kind!r} (one of: {', '.join(KINDS)})")
    if name in _TORCH_KINDS:
        from seedmap.detect.learned import require_torch

        require_torch()
    module, cls, _ = KINDS[name]
    return name, getattr(importlib.import_module(module), cls)


def _one_line(text: str) -> str:
    """The first sentence of a field's documentation, on one line."""
    text = " ".join(text.split()).replace("``", "`")
    return re.split(r"\.\s+(?=[A-Z0-9])", text, maxsplit=1)[0].rstrip(".")


@lru_cache(maxsize=None)
def _source_comments(cls: type) -> dict[str, str]:
    """{field: comment} of the fields ``cls`` itself declares: the ``#:`` lines above a field, else a
    trailing ``# ...`` on its lines. Empty when the source cannot be read."""
    try:
        src = textwrap.dedent(inspect.getsource(cls))
        tree = ast.parse(src)
        comments = {tok.start[0]: tok.string for tok in tokenize.generate_tokens(io.StringIO(src).readline)
                    if tok.type == tokenize.COMMENT}
    except (OSError, TypeError, SyntaxError, tokenize.TokenError):
        return {}
    body = tree.body[0].body if tree.body and isinstance(tree.body[0], ast.ClassDef) else []
    out: dict[str, str] = {}
    for node in body:
        if not (isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name)):
            continue
        above, line = [], node.lineno - 1
        while comments.get(line, "").startswith("#:"):
            above.insert(0, comments[line][2:].strip())
            line -= 1
        trailing = [c.lstrip("#").strip() for ln in range(node.lineno, (node.end_lineno or node.lineno) + 1)
                    if (c := comments.get(ln)) and not c.startswith("#:")
                    and not re.match(r"#\s*(noqa|type:|pragma)", c)]
        text = " ".join(above) or (trailing[0] if trailing else "")
        if text:
            out[node.target.id] = text
    return out


def field_doc(model: type[BaseModel], name: str) -> str:
    """One line describing field ``name`` of ``model`` ('' when it is undocumented)."""
    info = model.model_fields[name]
    if info.description:
        return _one_line(info.description)
    for klass in model.__mro__:  # the nearest class that declares the field with a comment (a subclass may
        if name in klass.__dict__.get("__annotations__", {}):  # only change the default)
            if text := _source_comments(klass).get(name):
                return _one_line(text)
    return ""


def _class_doc(value: BaseModel) -> str:
    doc = type(value).__doc__
    return _one_line(doc) if doc and doc is not BaseModel.__doc__ else ""


def _flow(value: Any) -> str:
    """``value`` as one line of YAML (flow style: ``[4.5, 1.5]``, ``{a: 1}``, ``null``, quoted strings)."""
    return yaml.safe_dump([value], default_flow_style=True, width=float("inf"), allow_unicode=True).strip()[1:-1]


def _emit(value: BaseModel, depth: int, lines: list[str], only: Optional[str] = None) -> None:
    """Append the YAML lines of ``value``'s fields (only field ``only`` when given) at ``depth``."""
    pad = "  " * depth
    dumped = value.model_dump(mode="json")
    for name in type(value).model_fields:
        if only is not None and name != only:
            continue
        sub = getattr(value, name)
        doc = field_doc(type(value), name) or (_class_doc(sub) if isinstance(sub, BaseModel) else "")
        if doc:
            lines.append(f"{pad}# {doc}")
        if isinstance(sub, BaseModel):
            lines.append(f"{pad}{name}:")
            _emit(sub, depth + 1, lines)
        else:
            lines.append(f"{pad}{name}: {_flow(dumped[name])}")


def config_yaml(cfg: BaseModel, section: Optional[str] = None) -> str:
    """``cfg`` as YAML with one comment line per documented field; ``section`` (dotted, e.g.
    ``association`` or ``detect.cnn``) keeps only that part, under its keys, so the text stays a valid
    config file."""
    lines: list[str] = []
    if not section:
        _emit(cfg, 0, lines)
        return "\n".join(lines) + "\n"
    parts = section.split(".")
    node: Any = cfg
    for i, part in enumerate(parts):
        if not isinstance(node, BaseModel) or part not in type(node).model_fields:
            where = ".".join(parts[:i])
            if not isinstance(node, BaseModel):
                raise SeedmapError(f"unknown section {section!r}: {where!r} is a value, not a section")
            subs = [n for n in type(node).model_fields if isinstance(getattr(node, n), BaseModel)]
            raise SeedmapError(f"unknown section {section!r} (sections{' of ' + repr(where) if where else ''}: "
                               f"{', '.join(subs) or 'none'})")
        if i == len(parts) - 1:
            _emit(node, i, lines, only=part)
        else:
            lines.append(f"{'  ' * i}{part}:")
            node = getattr(node, part)
    return "\n".join(lines) + "\n"


@config_app.command("show")
def config_show_cmd(
    kind: str = typer.Argument(..., help="Which command's config: " + ", ".join(KINDS)
                               + " (also batch, count, recon, sim, panicle)."),
    section: Optional[str] = typer.Argument(None, help="Show only this section, e.g. association or detect.cnn."),
    config: Optional[Path] = ConfigOpt,
    set_: Optional[List[str]] = SetOpt,
) -> None:
    """Print the resolved config (defaults <- --config <- --set) as YAML, one comment line per field;
    the output is a valid --config file."""
    from seedmap.config import load_config

    name, cls = config_class(kind)
    cfg = load_config(cls, config, set_ or [])
    text = config_yaml(cfg, section)
    typer.echo(f"# config of {KINDS[name][2]} (pass an edited copy with --config FILE)")
    typer.echo(text, nl=False)
