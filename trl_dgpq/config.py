"""One source of truth for settings: config dataclasses.

Every env and agent has one dataclass; its fields hold the defaults, and each
field's metadata holds the help text and the field's constraints (a range, a
length, choices; rarely a flag name). From these the command line, ``--set
key=value``, presets, ``config.json`` and the checks are all derived, so a new
setting is one new field.

    @dataclass
    class MyConfig:
        gamma: float = setting(0.99, "discount", within="[0, 1]")
        widths: Tuple[int, ...] = setting((64,), "hidden widths", within="[1, inf)", length=(1, None))
        gp: GPConfig = nested(GPConfig)      # a sub-config, flattened: --noise-var, --set gp.noise_var=...

        def cross_check(self):               # only what relates fields to each other
            ...

``check_config(cfg)`` checks every declared constraint (nested configs too), then
``cross_check``; it is the one check, made before any work.

A *leaf* is a non-dataclass field; its *key* is the field name (or metadata
``flag``), unique across a config tree, and its *path* is the dotted field path.
Values given as text (CLI) or JSON are parsed against the field's type here,
with one-line errors.
"""
from __future__ import annotations

import dataclasses
import functools
import math
import re
import typing
from dataclasses import dataclass, field, fields, is_dataclass
from typing import Any, Callable, Dict, List, Optional, Tuple

# A config class's field types, evaluated once per class: with ``from __future__ import
# annotations`` each call compiles every annotation again, and resolving the reproduction's
# 120 configs asked for them ~7,000 times (3 of its 4 seconds). Callers only read the dict.
type_hints = functools.lru_cache(maxsize=None)(typing.get_type_hints)


@dataclass(frozen=True)
class Interval:
    """A range of numbers written as in mathematics: "[0, 1]", "(0, inf)", "[1, inf)"."""
    low: float
    high: float
    closed_low: bool
    closed_high: bool

    @classmethod
    def parse(cls, text: str) -> "Interval":
        m = re.fullmatch(r"\s*([\[(])\s*(-?inf|[-+.\deE]+)\s*,\s*(-?inf|[-+.\deE]+)\s*([\])])\s*", text)
        if not m:
            raise TypeError(f"not an interval: {text!r} (write e.g. [0, 1] or (0, inf))")
        return cls(float(m.group(2)), float(m.group(3)), m.group(1) == "[", m.group(4) == "]")

    def __contains__(self, v) -> bool:
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            return False
        above = v >= self.low if self.closed_low else v > self.low
        below = v <= self.high if self.closed_high else v < self.high
        return above and below and (math.isfinite(v) or v in (self.low, self.high))

    def __str__(self) -> str:
        g = lambda v: f"{v:g}"  # noqa: E731
        if (self.low, self.high) == (-math.inf, math.inf):
            return "finite" if not (self.closed_low or self.closed_high) else f"in {self.describe_ends()}"
        if self.high == math.inf:
            return f"{'>=' if self.closed_low else '>'} {g(self.low)}"
        if self.low == -math.inf:
            return f"{'<=' if self.closed_high else '<'} {g(self.high)}"
        return f"in {self.describe_ends()}"

    def describe_ends(self) -> str:
        return f"{'[' if self.closed_low else '('}{self.low:g}, {self.high:g}{']' if self.closed_high else ')'}"


def setting(default, help: str, *, choices: Optional[Tuple[str, ...]] = None, flag: Optional[str] = None,
            parse: Optional[Callable[[Any], Any]] = None, within: Optional[str] = None, length=None):
    """A config field: its default, its help text, and optionally its choices, its range
    ``within`` (of the number, or of each item of a tuple), the ``length`` of a tuple
    (a count, or (fewest, most) with None for no bound), a flag name or a parser."""
    meta = dict(help=help, choices=choices, flag=flag, parse=parse,
                within=Interval.parse(within) if within else None, length=length)
    return field(default=default, metadata=meta)


def check_value(key: str, meta, value) -> None:
    """One-line ValueError unless ``value`` meets the constraints declared in ``meta``."""
    if value is None:  # Optional settings: None is their "not given"
        return
    choices, within, length = meta.get("choices"), meta.get("within"), meta.get("length")
    if choices and value not in choices:
        raise ValueError(f"{key} must be one of {list(choices)}, got {value!r}")
    items = list(value) if isinstance(value, (tuple, list)) else None
    if length is not None and items is not None:
        fewest, most = (length, length) if isinstance(length, int) else length
        if len(items) < fewest or (most is not None and len(items) > most):
            count = (f"{fewest}" if fewest == most else f"at least {fewest}" if most is None
                     else f"{fewest} to {most}")
            one = (most if most is not None else fewest) == 1
            raise ValueError(f"{key} needs {count} value{'' if one else 's'}, got {items}")
    if within is not None and not all(v in within for v in (items if items is not None else [value])):
        raise ValueError(f"{key} must {'each ' if items is not None else ''}be {within}, got "
                         f"{items if items is not None else value}")


def check_config(cfg):
    """``cfg`` with every declared constraint checked (nested configs too), then its class's
    ``cross_check()`` if it has one; a one-line ValueError for the first that fails."""
    for f in fields(cfg):
        value = getattr(cfg, f.name)
        if is_dataclass(value):
            check_config(value)
        else:
            check_value(f.metadata.get("flag") or f.name, f.metadata, value)
    cross = getattr(cfg, "cross_check", None)
    if cross is not None:
        cross()
    return cfg


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
    hints = type_hints(cls)
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


def leaf_names(cls) -> Dict[str, Leaf]:
    """{flat key or dotted path: leaf} of ``cls``, the first leaf a name fits winning."""
    names: Dict[str, Leaf] = {}
    for leaf in leaves(cls):
        names.setdefault(leaf.key, leaf)
        names.setdefault(".".join(leaf.path), leaf)
    return names


# built once per class: ``with_overrides`` looks up every setting of every config it resolves
_leaf_names = functools.lru_cache(maxsize=None)(leaf_names)


def find_leaf(cls, key: str) -> Optional[Leaf]:
    """The leaf of ``cls`` named by flat key ``noise_var`` or dotted path ``gp.noise_var``."""
    return _leaf_names(cls).get(key)


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
    their defaults, unknown ones raise ValueError, values are parsed, type-checked and
    checked against their constraints (``check_config``)."""
    if not isinstance(d, dict):
        raise ValueError(f"{cls.__name__} settings must be a mapping, got {type(d).__name__}")
    if hasattr(cls, "upgrade"):  # the class brings a dict recorded in an older layout up to date
        d = cls.upgrade(d)
    hints = type_hints(cls)
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
    return check_config(cls(**kw))


def describe_default(leaf: Leaf) -> str:
    d = leaf.default
    if isinstance(d, tuple):
        return ",".join(map(str, d)) if d else "(none)"
    return str(d)
