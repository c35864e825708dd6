"""Typed configuration: pydantic models with YAML load/dump and ``key.sub=value`` CLI overrides.

Every module defines its own model (``SimConfig``, ``SlamConfig``, ...) deriving from
:class:`ConfigModel`; commands load them with :func:`load_config` and write the resolved
config next to their results with :func:`dump_config`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence, TypeVar

import yaml
from pydantic import BaseModel, ConfigDict, ValidationError

from seedmap.errors import ConfigError

T = TypeVar("T", bound="ConfigModel")


class ConfigModel(BaseModel):
    """Base for all seedmap configs: unknown keys are errors, assignments are validated, NaN and inf are refused."""

    model_config = ConfigDict(extra="forbid", validate_assignment=True, allow_inf_nan=False)


def _set_dotted(data: dict, key: str, value: Any) -> None:
    parts = key.split(".")
    node = data
    for p in parts[:-1]:
        nxt = node.get(p)
        if nxt is None:
            nxt = node[p] = {}
        if not isinstance(nxt, dict):
            raise ConfigError(f"override {key!r}: {p!r} is not a section")
        node = nxt
    node[parts[-1]] = value


def apply_overrides(data: dict, overrides: Sequence[str]) -> dict:
    """Apply ``section.key=value`` strings (values parsed as YAML scalars/lists) to a dict."""
    for item in overrides:
        if "=" not in item:
            raise ConfigError(f"override {item!r} is not of the form key=value")
        key, raw = item.split("=", 1)
        try:
            value = yaml.safe_load(raw) if raw.strip() else raw
        except yaml.YAMLError:
            value = raw
        _set_dotted(data, key.strip(), value)
    return data


def deep_merge(base: dict, extra: dict) -> dict:
    """``extra`` over ``base``, nested mappings merged key by key (neither argument is modified)."""
    out = dict(base)
    for k, v in extra.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = deep_merge(out[k], v)
        else:
            out[k] = v
    return out


def load_config(
    cls: type[T],
    path: str | Path | None = None,
    overrides: Sequence[str] = (),
    base: dict | None = None,
) -> T:
    """Build ``cls`` from defaults <- ``base`` <- YAML file <- CLI overrides (later wins)."""
    data: dict = dict(base or {})
    if path is not None:
        p = Path(path)
        if not p.is_file():
            raise ConfigError("config file not found", p)
        try:
            loaded = yaml.safe_load(p.read_text(encoding="utf-8")) or {}
        except UnicodeDecodeError:
            raise ConfigError("not a UTF-8 text file (a YAML config is expected)", p) from None
        except OSError as e:
            raise ConfigError(f"cannot read ({e.strerror or e})", p) from None
        except yaml.YAMLError as e:
            raise ConfigError(f"not valid YAML ({str(e).splitlines()[0]})", p) from None
        if not isinstance(loaded, dict):
            raise ConfigError("config must be a YAML mapping", p)
        data = deep_merge(data, loaded)
    data = apply_overrides(data, overrides)
    try:
        return cls.model_validate(data)
    except ValidationError as e:
        errs = e.errors()
        err = errs[0]
        loc = _field_loc(err["loc"])
        where = ".".join(str(x) for x in loc)
        if err["type"] == "extra_forbidden":
            raise ConfigError(f"unknown config key {where!r}{_key_hint(cls, loc)}", path) from None
        # a union (e.g. exposure: 'auto' | float) fails once per member: say what each would accept
        msgs = list(dict.fromkeys(x["msg"] for x in errs if _field_loc(x["loc"]) == loc))
        got = repr(err.get("input"))
        got = f" (got {got})" if len(got) <= 40 and len(msgs) > 1 else ""
        raise ConfigError(f"invalid config value {where!r}{got}: {' or '.join(msgs)}", path) from None


#: pydantic's names of union members in an error location (``('exposure', "literal['auto']")``)
_UNION_TAGS = {"float", "int", "str", "bool", "none", "list", "dict", "tuple", "set", "bytes", "path"}


def _field_loc(loc: tuple) -> tuple:
    """The config key path of a pydantic error location, without union-member tags."""
    return tuple(x for x in loc if not (isinstance(x, str) and (x in _UNION_TAGS or "[" in x)))


def _key_hint(cls: type[BaseModel], loc: tuple) -> str:
    """`` (did you mean 'a.b'?)`` for a mistyped key, else the keys its section has (a typo is the usual cause)."""
    import difflib

    model: Any = cls
    for part in loc[:-1]:
        field = model.model_fields.get(str(part)) if isinstance(model, type) and issubclass(model, BaseModel) else None
        model = field.annotation if field is not None else None
    if not (isinstance(model, type) and issubclass(model, BaseModel)):
        return ""
    keys = list(model.model_fields)
    prefix = "".join(f"{p}." for p in loc[:-1])
    close = difflib.get_close_matches(str(loc[-1]), keys, n=1)
    if close:
        return f" (did you mean {prefix + close[0]!r}?)"
    shown = ", ".join(keys[:15]) + (f", ... ({len(keys)} keys)" if len(keys) > 15 else "")
    return f" ({prefix.rstrip('.') or 'the config'} has: {shown})"


def config_to_yaml(cfg: BaseModel) -> str:
    return yaml.safe_dump(cfg.model_dump(mode="json"), sort_keys=False)


def dump_config(cfg: BaseModel, path: str | Path) -> None:
    from seedmap.io.atomic import atomic_write_text

    atomic_write_text(Path(path), config_to_yaml(cfg))
