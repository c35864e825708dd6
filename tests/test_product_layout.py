"""The tree stays a product: small modules, a readable configuration, no import cycles, no work-log words."""

from __future__ import annotations

import ast
import importlib
import inspect
import pkgutil
import re
import subprocess
from pathlib import Path

import pytest

import seedmap
from seedmap.config import ConfigModel

ROOT = Path(__file__).resolve().parents[1]
PKG = ROOT / "seedmap"

MAX_MODULE_LINES = 800
MAX_CONFIG_LEAVES = 250
README_MAX_LINES = 300


def _modules() -> dict[str, Path]:
    out = {}
    for p in sorted(PKG.rglob("*.py")):
        rel = p.relative_to(ROOT).with_suffix("")
        parts = list(rel.parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = p
    return out


def test_no_module_over_the_line_limit():
    long = {name: n for name, p in _modules().items() if (n := len(p.read_text().splitlines())) > MAX_MODULE_LINES}
    assert not long, f"modules over {MAX_MODULE_LINES} lines: {long}"


def _imports(name: str, path: Path, modules: dict[str, Path]) -> set[str]:
    """seedmap modules imported anywhere in ``path`` (function-level imports included)."""
    tree = ast.parse(path.read_text())
    is_pkg = path.name == "__init__.py"
    base = name if is_pkg else name.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                anchor = base.split(".")
                anchor = anchor[: len(anchor) - (node.level - 1)]
                mod = ".".join(anchor + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            # ``from pkg import sub`` names a submodule when one exists
            targets = [f"{mod}.{a.name}" if f"{mod}.{a.name}" in modules else mod for a in node.names]
        else:
            continue
        for t in targets:
            while t and t not in modules:
                t = t.rpartition(".")[0]
            if t and t != name and t.startswith("seedmap"):
                found.add(t)
    return found


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []
    counter = [0]

    def visit(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_no_import_cycles():
    """Package ``__init__`` re-exports count as edges: a submodule must not import its own package root."""
    mods = _modules()
    graph = {name: _imports(name, p, mods) for name, p in mods.items()}
    # a package importing its own submodules is how re-exports work; only the reverse closes a cycle
    cycles = _cycles(graph)
    assert not cycles, "import cycles: " + "; ".join(" <-> ".join(c) for c in cycles)


def _config_classes() -> set[type]:
    for m in pkgutil.walk_packages(seedmap.__path__, "seedmap."):
        if m.name.startswith("seedmap.detect.learned") and m.name.rsplit(".", 1)[-1] in {"torch_models"}:
            continue
        try:
            importlib.import_module(m.name)
        except ImportError:  # an optional extra (torch, ray) that is not installed
            continue
    seen: set[type] = set()
    todo = list(ConfigModel.__subclasses__())
    while todo:
        c = todo.pop()
        if c not in seen:
            seen.add(c)
            todo.extend(c.__subclasses__())
    return seen


def _own_leaves(cls: type) -> list[str]:
    parents = [b for b in cls.__mro__[1:] if inspect.isclass(b) and issubclass(b, ConfigModel)]
    out = []
    for fname, f in cls.model_fields.items():
        if any(fname in b.model_fields for b in parents):
            continue
        a = f.annotation
        if inspect.isclass(a) and issubclass(a, ConfigModel):
            continue  # a section, not a leaf
        out.append(fname)
    return out


def test_configuration_stays_readable():
    classes = _config_classes()
    total = sum(len(_own_leaves(c)) for c in classes)
    assert total <= MAX_CONFIG_LEAVES, f"{total} config leaf fields (at most {MAX_CONFIG_LEAVES})"


def _tracked_files() -> list[Path]:
    try:
        out = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True, check=True).stdout
    except (OSError, subprocess.CalledProcessError):
        pytest.skip("not a git checkout")
    return [ROOT / f for f in out.splitlines() if (ROOT / f).is_file()]


def test_the_project_speaks_only_of_itself():
    """No words of work periods (numbered work sittings, run tags in file names) in names or text; versions, commits
    and dates instead."""
    w = "sess" "ion"  # the word itself, spelt so that this file does not contain it
    word = re.compile(rf"\b{w}s?[ -]?\d|\b{w}s\b|\b(this|that|earlier|later|previous|next|each|every|one|"
                      rf"same|last|first|second|a|the|work|per) {w}\b", re.IGNORECASE)
    me = Path(__file__).resolve()
    bad = []
    for p in _tracked_files():
        if p.resolve() == me or p.suffix in {".onnx", ".safetensors", ".png", ".jpg", ".npz", ".gz", ".bag"}:
            continue
        if re.search(r"(^|_)s\d{1,2}(_|\.|$)", p.stem + p.suffix):
            bad.append(f"{p.relative_to(ROOT)} (name)")
            continue
        try:
            text = p.read_text()
        except UnicodeDecodeError:
            continue
        for i, line in enumerate(text.splitlines(), 1):
            if word.search(line):
                bad.append(f"{p.relative_to(ROOT)}:{i}")
                break
    assert not bad, "work-log words in: " + ", ".join(bad[:30]) + (f" ... ({len(bad)})" if len(bad) > 30 else "")


def test_readme_is_for_users():
    n = len((ROOT / "README.md").read_text().splitlines())
    assert n <= README_MAX_LINES, f"README.md has {n} lines (at most {README_MAX_LINES})"


def test_the_version_is_the_newest_changelog_release(monkeypatch, capsys):
    import re

    import seedmap
    from tests.helpers.cli import run_cli

    top = re.search(r"^## (\d+\.\d+\.\d+)", (ROOT / "CHANGELOG.md").read_text(), re.M)
    assert top is not None and seedmap.__version__ == top.group(1)
    assert run_cli(["--version"], monkeypatch) == 0
    assert capsys.readouterr().out.strip() == f"seedmap {seedmap.__version__}"
