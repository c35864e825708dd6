"""``seedmap config show``: the resolved config as commented YAML that loads back as the same config."""

from __future__ import annotations

import pytest
import yaml
from pydantic import Field

from seedmap.cli.config import KINDS, config_class, config_yaml, field_doc
from seedmap.config import ConfigModel, load_config

from helpers.cli import run_cli


class _Inner(ConfigModel):
    """Inner section. More words here."""

    #: a value documented above
    #: over two lines. Second sentence is dropped.
    a: int = 1
    b: list[float] = Field(default_factory=lambda: [1.5, 2.0])  # trailing comment


class _Outer(ConfigModel):
    x: float = Field(0.5, description="described in Field")
    name: str | None = None
    inner: _Inner = Field(default_factory=_Inner)
    table: dict[str, dict[str, int]] = Field(default_factory=lambda: {"k": {"v": 1}})


class _Child(_Outer):
    #: the child's own field
    extra: str = "yes: quoted"


class _InnerDefaults(_Inner):
    """Only a default changes."""

    a: int = 5


def _show(args: list, monkeypatch, capsys) -> tuple[int, str, str]:
    code = run_cli(["config", "show", *args], monkeypatch)
    out = capsys.readouterr()
    return code, out.out, out.err


def test_field_docs_from_description_comments_and_parents():
    assert field_doc(_Outer, "x") == "described in Field"
    assert field_doc(_Inner, "a") == "a value documented above over two lines"
    assert field_doc(_Inner, "b") == "trailing comment"
    assert field_doc(_Outer, "name") == ""
    assert field_doc(_Child, "extra") == "the child's own field"
    assert field_doc(_Child, "x") == "described in Field"  # declared by the parent class
    assert field_doc(_InnerDefaults, "a") == "a value documented above over two lines"  # the parent's comment


def test_yaml_has_one_comment_per_documented_field_and_loads_back(tmp_path):
    cfg = _Child(x=2.0, inner=_Inner(a=3))
    text = config_yaml(cfg)
    lines = text.splitlines()
    assert lines[:2] == ["# described in Field", "x: 2.0"]
    assert "name: null" in lines
    assert lines[lines.index("inner:") - 1] == "# Inner section"  # an undocumented section: its class docstring
    assert "  # a value documented above over two lines" in lines and "  a: 3" in lines
    assert "  b: [1.5, 2.0]" in lines
    assert yaml.safe_load(text) == cfg.model_dump(mode="json")
    (tmp_path / "c.yaml").write_text(text)
    assert load_config(_Child, tmp_path / "c.yaml") == cfg


def test_section_keeps_its_keys_so_it_stays_a_config():
    text = config_yaml(_Child(), "inner.b")
    assert text.splitlines() == ["inner:", "  # trailing comment", "  b: [1.5, 2.0]"]
    assert yaml.safe_load(config_yaml(_Child(), "inner")) == {"inner": {"a": 1, "b": [1.5, 2.0]}}


@pytest.mark.parametrize("kind", list(KINDS))
def test_every_kind_shows_its_defaults_as_a_loadable_config(kind, tmp_path, monkeypatch, capsys):
    if kind.startswith("train-"):
        pytest.importorskip("torch")
        pytest.importorskip("torchvision")
    code, out, err = _show([kind], monkeypatch, capsys)
    assert code == 0, err
    _, cls = config_class(kind)
    assert out.startswith("# config of seedmap ")
    assert yaml.safe_load(out) == cls().model_dump(mode="json")
    (tmp_path / "c.yaml").write_text(out)
    assert load_config(cls, tmp_path / "c.yaml") == cls()


def test_config_file_and_set_are_applied(tmp_path, monkeypatch, capsys):
    from seedmap.slam.config import SlamConfig

    (tmp_path / "my.yaml").write_text("backend:\n  stereo_sigma_px: 2.5\nmax_frames: 7\n")
    code, out, err = _show(["slam", "--config", tmp_path / "my.yaml", "--set", "lost.min_inliers=20"],
                           monkeypatch, capsys)
    assert code == 0, err
    shown = yaml.safe_load(out)
    assert shown["backend"]["stereo_sigma_px"] == 2.5 and shown["max_frames"] == 7 and shown["lost"]["min_inliers"] == 20
    expected = load_config(SlamConfig, tmp_path / "my.yaml", ["lost.min_inliers=20"])
    assert shown == expected.model_dump(mode="json")


def test_section_and_aliases(monkeypatch, capsys):
    from seedmap.recon.config import ReconConfig

    code, out, err = _show(["count", "count", "--set", "count.method=density"], monkeypatch, capsys)
    assert code == 0, err
    assert out.startswith("# config of seedmap reconstruct, count")
    shown = yaml.safe_load(out)
    assert list(shown) == ["count"]
    assert shown["count"] == ReconConfig(count={"method": "density"}).count.model_dump(mode="json")
    assert any(ln.startswith("  # ") for ln in out.splitlines())  # the fields' comments
    code, out, err = _show(["slam", "backend.stereo_sigma_px"], monkeypatch, capsys)
    assert code == 0 and yaml.safe_load(out) == {"backend": {"stereo_sigma_px": 1.0}}


@pytest.mark.parametrize("args, message", [
    (["nope"], "error: unknown config 'nope' (one of: slam, "),
    (["slam", "nope"], "error: unknown section 'nope' (sections: gates, "),
    (["slam", "backend.nope"], "error: unknown section 'backend.nope' (sections of 'backend': none)"),
    (["slam", "seed.x"], "error: unknown section 'seed.x': 'seed' is a value, not a section"),
    (["slam", "--set", "backend.nope=1"], "error: unknown config key 'backend.nope'"),
])
def test_unknown_kind_section_or_key_is_one_line_and_exit_2(args, message, monkeypatch, capsys):
    code, out, err = _show(args, monkeypatch, capsys)
    assert code == 2 and out == ""
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith(message), err
