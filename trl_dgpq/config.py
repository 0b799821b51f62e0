"""One source of truth for settings: config dataclasses.

Every env and agent has one dataclass; its fields hold the defaults, and each
field's metadata holds the help text (and, rarely, a flag name or choices).
From these the command line, ``--set key=value``, presets and ``config.json``
are all derived, so a new setting is one new field.

    @dataclass
    class MyConfig:
        gamma: float = setting(0.99, "discount")
        gp: GPConfig = nested(GPConfig)      # a sub-config, flattened: --noise-var, --set gp.noise_var=...

A *leaf* is a non-dataclass field; its *key* is the field name (or metadata
``flag``), unique across a config tree, and its *path* is the dotted field path.
Values given as text (CLI) or JSON are parsed against the field's type here,
with one-line errors.
"""
from __future__ import annotations

import dataclasses
import math
import typing
from dataclasses import dataclass, field, fields, is_dataclass
from typing import Any, Callable, Dict, List, Optional, Tuple


def setting(default, help: str, *, choices: Optional[Tuple[str, ...]] = None, flag: Optional[str] = None,
            parse: Optional[Callable[[Any], Any]] = None):
    """A config field: its default, its help text and optional choices, flag name or parser."""
    meta = dict(help=help, choices=choices, flag=flag, parse=parse)
    return field(default=default, metadata=meta)


def require_positive(cfg, *names: str) -> None:
    """One-line ValueError unless each named setting of ``cfg`` is a finite number > 0
    (for ``check()`` methods)."""
    for name in names:
        v = getattr(cfg, name)
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
            raise ValueError(f"{name} must be > 0, got {v}")


def nested(cls):
    """A sub-config field (defaults from ``cls``)."""
    return field(default_factory=cls, metadata=dict(help=cls.__doc__ or ""))


@dataclass(frozen=True)
class Leaf:
    key: str                 # flat name: CLI flag --key-with-dashes, --set key=...
    path: Tuple[str, ...]    # field path from the root config
    type: Any
    field: dataclasses.Field

    @property
    def help(self) -> str:
        return self.field.metadata.get("help", "")

    @property
    def choices(self):
        return self.field.metadata.get("choices")

    @property
    def default(self):
        f = self.field
        return f.default_factory() if f.default is dataclasses.MISSING else f.default


def leaves(cls, path: Tuple[str, ...] = ()) -> List[Leaf]:
    """The leaf fields of config class ``cls``, nested configs flattened."""
    hints = typing.get_type_hints(cls)
    out = []
    for f in fields(cls):
        tp = hints[f.name]
        if is_dataclass(tp):
            out += leaves(tp, path + (f.name,))
        else:
            out.append(Leaf(f.metadata.get("flag") or f.name, path + (f.name,), tp, f))
    keys = [leaf.key for leaf in out]
    dup = {k for k in keys if keys.count(k) > 1}
    if dup:
        raise TypeError(f"{cls.__name__}: setting names must be unique, repeated: {sorted(dup)}")
    return out


def find_leaf(cls, key: str) -> Optional[Leaf]:
    """The leaf of ``cls`` named by flat key ``noise_var`` or dotted path ``gp.noise_var``."""
    for leaf in leaves(cls):
        if key in (leaf.key, ".".join(leaf.path)):
            return leaf
    return None


def parse_value(leaf: Leaf, value):
    """``value`` (CLI text or a JSON value) converted to the leaf's type; ValueError
    with one line if it does not fit."""
    custom = leaf.field.metadata.get("parse")
    if custom is not None:
        return custom(value)
    tp, name = leaf.type, leaf.key
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin is typing.Union and type(None) in args:  # Optional[X]
        if value is None or (isinstance(value, str) and value.strip().lower() in ("none", "null")):
            return None
        tp = next(a for a in args if a is not type(None))
        origin, args = typing.get_origin(tp), typing.get_args(tp)
    if value is None:
        raise ValueError(f"{name} cannot be none")
    if tp is bool:
        if isinstance(value, bool):
            return value
        text = str(value).strip().lower()
        if text in ("true", "1", "yes", "on"):
            return True
        if text in ("false", "0", "no", "off"):
            return False
        raise ValueError(f"{name} must be true or false, got {value!r}")
    if tp is int:
        if isinstance(value, bool):
            raise ValueError(f"{name} must be an integer, got {value!r}")
        if isinstance(value, int):
            return value
        if isinstance(value, float) and value.is_integer():
            return int(value)
        try:
            return int(str(value).strip())
        except ValueError:
            raise ValueError(f"{name} must be an integer, got {value!r}") from None
    if tp is float:
        if isinstance(value, bool):
            raise ValueError(f"{name} must be a number, got {value!r}")
        try:
            return float(value)
        except (TypeError, ValueError):
            raise ValueError(f"{name} must be a number, got {value!r}") from None
    if tp is str:
        if not isinstance(value, str):
            raise ValueError(f"{name} must be text, got {value!r}")
        if leaf.choices and value not in leaf.choices:
            raise ValueError(f"{name} must be one of {list(leaf.choices)}, got {value!r}")
        return value
    if origin in (tuple, list) and args:
        inner = args[0]
        items = value.split(",") if isinstance(value, str) else value
        if not isinstance(items, (list, tuple)):
            raise ValueError(f"{name} must be a comma-separated list, got {value!r}")
        item_leaf = Leaf(name, leaf.path, inner, dataclasses.field())
        try:
            return tuple(parse_value(item_leaf, v.strip() if isinstance(v, str) else v)
                         for v in items if not (isinstance(v, str) and not v.strip()))
        except ValueError:
            raise ValueError(f"{name} must be a comma-separated list of {inner.__name__}, got {value!r}") from None
    raise TypeError(f"{name}: unsupported setting type {tp}")


def with_overrides(cfg, overrides: Dict[str, Any]):
    """A copy of config ``cfg`` with ``{key or dotted path: value}`` applied (values
    parsed against the field types). Unknown keys raise ValueError."""
    d, cls = to_dict(cfg), type(cfg)
    for key, value in overrides.items():
        leaf = find_leaf(cls, key)
        if leaf is None:
            raise ValueError(f"unknown setting {key!r} for {cls.__name__}")
        node = d
        for p in leaf.path[:-1]:
            node = node[p]
        node[leaf.path[-1]] = parse_value(leaf, value)
    return from_dict(cls, d)


def to_dict(cfg) -> dict:
    """Nested plain dict (tuples as lists), JSON-able."""
    def plain(v):
        if isinstance(v, dict):
            return {k: plain(x) for k, x in v.items()}
        if isinstance(v, (list, tuple)):
            return [plain(x) for x in v]
        return v
    return plain(dataclasses.asdict(cfg))


def from_dict(cls, d: dict):
    """Config ``cls`` from a nested dict (as ``to_dict`` writes it); missing fields take
    their defaults, unknown ones raise ValueError, values are parsed and type-checked."""
    if not isinstance(d, dict):
        raise ValueError(f"{cls.__name__} settings must be a mapping, got {type(d).__name__}")
    hints = typing.get_type_hints(cls)
    names = {f.name: f for f in fields(cls)}
    unknown = sorted(set(d) - set(names))
    if unknown:
        raise ValueError(f"unknown {cls.__name__} settings: {unknown}")
    kw = {}
    for name, value in d.items():
        tp = hints[name]
        if is_dataclass(tp):
            kw[name] = from_dict(tp, value)
        else:
            f = names[name]
            kw[name] = parse_value(Leaf(f.metadata.get("flag") or name, (name,), tp, f), value)
    return cls(**kw)


def describe_default(leaf: Leaf) -> str:
    d = leaf.default
    if isinstance(d, tuple):
        return ",".join(map(str, d)) if d else "(none)"
    return str(d)
