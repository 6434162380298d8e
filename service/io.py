"""Saving and loading stage values (frozen dataclasses of arrays and scalars) to a folder.

A stage's outputs are written as ``arrays.npz`` (every numpy field, including inside nested
dataclasses and lists) plus ``values.json`` (everything else), so they can be cached in the artifact
store and read back bit-identically. Only dataclasses, numpy arrays, lists/tuples, dicts with string
keys, and JSON scalars are supported: that keeps stage values plain.
"""

from __future__ import annotations

import dataclasses
import json
import types
import typing
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

T = TypeVar("T")

_ARR = "__array__"


def _encode(value: Any, key: str, arrays: dict[str, np.ndarray]) -> Any:
    if isinstance(value, np.ndarray):
        arrays[key] = value
        return {_ARR: key}
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: _encode(getattr(value, f.name), f"{key}.{f.name}", arrays) for f in dataclasses.fields(value)}
    if isinstance(value, (list, tuple)):
        return [_encode(v, f"{key}[{i}]", arrays) for i, v in enumerate(value)]
    if isinstance(value, dict):
        return {str(k): _encode(v, f"{key}/{k}", arrays) for k, v in value.items()}
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, (np.floating, np.integer, np.bool_)):
        return value.item()
    return value


def _decode(tp: Any, raw: Any, arrays: Any) -> Any:
    if isinstance(raw, dict) and set(raw) == {_ARR}:
        return arrays[raw[_ARR]]
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if origin is typing.Union or origin is types.UnionType:
        if raw is None:
            return None
        non_none = [a for a in args if a is not type(None)]
        return _decode(non_none[0], raw, arrays) if len(non_none) == 1 else raw
    if dataclasses.is_dataclass(tp):
        hints = typing.get_type_hints(tp)
        return tp(**{f.name: _decode(hints[f.name], raw[f.name], arrays) for f in dataclasses.fields(tp) if f.name in raw})
    if origin in (list, tuple) and isinstance(raw, list):
        if origin is tuple and args and args[-1] is not Ellipsis:
            return tuple(_decode(a, r, arrays) for a, r in zip(args, raw))
        inner = args[0] if args else Any
        seq = [_decode(inner, r, arrays) for r in raw]
        return tuple(seq) if origin is tuple else seq
    if origin is dict and isinstance(raw, dict):
        inner = args[1] if len(args) == 2 else Any
        return {k: _decode(inner, v, arrays) for k, v in raw.items()}
    if tp is Path and isinstance(raw, str):
        return Path(raw)
    return raw


def save_value(value: Any, folder: Path) -> None:
    """Write a stage value into ``folder`` (created if needed)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    arrays: dict[str, np.ndarray] = {}
    tree = _encode(value, "v", arrays)
    np.savez(folder / "arrays.npz", **arrays)
    (folder / "values.json").write_text(json.dumps(tree, indent=1, allow_nan=True))


def load_value(cls: type[T], folder: Path) -> T:
    """Read back a value written by :func:`save_value` as an instance of ``cls``."""
    folder = Path(folder)
    tree = json.loads((folder / "values.json").read_text())
    with np.load(folder / "arrays.npz", allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    return _decode(cls, tree, arrays)
