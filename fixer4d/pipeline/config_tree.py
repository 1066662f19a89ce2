"""Typed configuration trees: nested dataclasses built from plain dicts, validated in full.

Every stage defines its own dataclass beside the stage (``TrainingConfig`` in train/config.py,
``InitConfig`` in init/run.py, ...); ``RunConfig`` nests them. This module turns a partial nested
dict (defaults, a config file, ``--set`` overrides) into that tree and checks everything before
anything is written: unknown keys (with "did you mean ..."), wrong types and each dataclass's own
range checks (its ``__post_init__``), always naming the dotted key. A dataclass may define a
classmethod ``from_partial(**given)`` that builds it from the keys actually given (used by
``TrainingConfig`` to scale its schedule to the iterations unless the schedule is given).
"""
from __future__ import annotations

import dataclasses
import difflib
import json
import math
import types
import typing
from typing import Any, Literal, Union

from fixer4d.errors import InputError


def suggest(name: str, known: list[str]) -> str:
    """' (did you mean X?)' for the closest known name, or ''."""
    close = difflib.get_close_matches(name, known, n=1, cutoff=0.6)
    return f" (did you mean {close[0]!r}?)" if close else ""


def build(cls: type, data: dict[str, Any] | None, path: str = "") -> Any:
    """Instantiate dataclass ``cls`` from a (partial) nested dict, checking names and types.

    Missing keys take the dataclass defaults; nested dataclass fields recurse. Raises InputError
    naming the dotted key for an unknown key, a wrong type or a value the dataclass rejects.
    """
    data = {} if data is None else data
    if not isinstance(data, dict):
        raise InputError(f"{path or 'config'}: expected a section (JSON object), got {type(data).__name__} {data!r}")
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    kwargs: dict[str, Any] = {}
    for key, value in data.items():
        where = f"{path}.{key}" if path else key
        if key not in fields:
            known = sorted(fields)
            listing = (f"{'[' + path + ']' if path else 'the config'} has: {', '.join(known)}" if len(known) <= 12
                       else "`fixer4d run SCENE --print-config` lists every key")
            raise InputError(f"unknown config key {where!r}{suggest(key, known)}; {listing}")
        kwargs[key] = _coerce(hints[key], value, where)
    try:
        if hasattr(cls, "from_partial"):
            return cls.from_partial(**kwargs)
        return cls(**kwargs)
    except InputError as exc:
        raise InputError(f"{path or 'config'}: {exc}") from None
    except (TypeError, ValueError) as exc:
        raise InputError(f"{path or 'config'}: {exc}") from None


def _coerce(tp: Any, value: Any, where: str) -> Any:
    """``value`` checked against annotation ``tp`` (ints widen to floats, lists to tuples)."""
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if tp is Any:
        return value
    if dataclasses.is_dataclass(tp):
        if dataclasses.is_dataclass(value):
            value = dataclasses.asdict(value)
        return build(tp, value, where)
    if origin in (Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        errors = []
        for option in (a for a in args if a is not type(None)):
            try:
                return _coerce(option, value, where)
            except InputError as exc:
                errors.append(str(exc))
        raise InputError(errors[0] if len(errors) == 1 else
                         f"{where}: {value!r} does not fit {_name(tp)}")
    if origin is Literal:
        if value not in args:
            choices = [str(a) for a in args]
            hint = suggest(str(value), choices) if isinstance(value, str) else ""
            raise InputError(f"{where}: {value!r} is not one of {', '.join(repr(a) for a in args)}{hint}")
        return value
    if tp is bool:
        if not isinstance(value, bool):
            raise InputError(f"{where}: expected true or false, got {value!r}")
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            if isinstance(value, float) and value.is_integer():
                return int(value)
            raise InputError(f"{where}: expected an integer, got {value!r}")
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise InputError(f"{where}: expected a number, got {value!r}")
        try:
            number = float(value)
        except OverflowError:  # an integer beyond float range
            number = math.inf
        if not math.isfinite(number):
            raise InputError(f"{where}: expected a finite number, got {value!r}")
        return number
    if tp is str:
        if not isinstance(value, str):
            raise InputError(f"{where}: expected a string, got {value!r}")
        return value
    if origin in (list, tuple):
        if not isinstance(value, (list, tuple)):
            raise InputError(f"{where}: expected a list, got {value!r}")
        if origin is tuple and args and args[-1] is not Ellipsis:
            if len(args) != len(value):
                raise InputError(f"{where}: expected {len(args)} values, got {len(value)}")
            return tuple(_coerce(a, v, f"{where}[{i}]") for i, (a, v) in enumerate(zip(args, value)))
        item = args[0] if args else Any
        out = [_coerce(item, v, f"{where}[{i}]") for i, v in enumerate(value)]
        return tuple(out) if origin is tuple else out
    if origin is dict:
        if not isinstance(value, dict):
            raise InputError(f"{where}: expected a JSON object, got {value!r}")
        return dict(value)
    return value


def _name(tp: Any) -> str:
    return getattr(tp, "__name__", None) or str(tp).replace("typing.", "")


def to_dict(obj: Any) -> dict[str, Any]:
    """A dataclass tree as plain JSON types (tuples become lists)."""
    return json.loads(json.dumps(dataclasses.asdict(obj)))


def set_dotted(tree: dict[str, Any], key: str, value: Any) -> None:
    """Set ``tree["a"]["b"] = value`` for key ``"a.b"``, creating sections as needed (the
    dataclass build later says whether the key exists)."""
    parts = key.split(".")
    if not all(parts):
        raise InputError(f"override {key!r}: empty name in a dotted key")
    node = tree
    for p in parts[:-1]:
        child = node.get(p)
        if child is None:
            child = node[p] = {}
        elif not isinstance(child, dict):
            raise InputError(f"override {key!r}: {p!r} is a value ({child!r}), not a section")
        node = child
    node[parts[-1]] = value


def get_dotted(tree: dict[str, Any], key: str) -> Any:
    node: Any = tree
    for p in key.split("."):
        if not isinstance(node, dict) or p not in node:
            return None
        node = node[p]
    return node


def merge(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    """Recursive dict merge: ``over`` wins, sections merge."""
    out = dict(base)
    for k, v in over.items():
        out[k] = merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def parse_set_overrides(items: list[str]) -> dict[str, Any]:
    """``--set KEY=VALUE`` arguments -> {dotted key: value}; values are JSON where they parse
    (numbers, lists, true/false, null), strings otherwise."""
    out: dict[str, Any] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise InputError(f"--set {item!r}: expected KEY=VALUE, e.g. training.iterations=800")
        try:
            out[key.strip()] = json.loads(value)
        except json.JSONDecodeError:
            out[key.strip()] = value
    return out


def diff(a: dict[str, Any], b: dict[str, Any], prefix: str = "") -> list[str]:
    """Dotted keys whose values differ between two nested dicts, as 'key: a -> b'."""
    out = []
    for k in sorted(set(a) | set(b)):
        where = f"{prefix}.{k}" if prefix else k
        va, vb = a.get(k), b.get(k)
        if isinstance(va, dict) and isinstance(vb, dict):
            out += diff(va, vb, where)
        elif va != vb:
            out.append(f"{where}: {json.dumps(va)} -> {json.dumps(vb)}")
    return out
