"""Block states to flat arrays and back, so a checkpoint can hold them.

A state is a frozen dataclass whose fields are numbers, strings, numpy arrays, None, or
(nested) frozen dataclasses of the same; nested fields are stored as ``prefix/field/sub``.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

_NONE = "__none__"


def to_arrays(prefix: str, state: Any) -> dict[str, np.ndarray]:
    """Flatten a state dataclass into ``{prefix/field: array}``."""
    out: dict[str, np.ndarray] = {}
    if state is None:
        out[prefix] = np.array(_NONE)
        return out
    if not dataclasses.is_dataclass(state):
        out[prefix] = np.asarray(state)
        return out
    out[prefix + "/__class__"] = np.array(type(state).__qualname__)
    for f in dataclasses.fields(state):
        out.update(to_arrays(f"{prefix}/{f.name}", getattr(state, f.name)))
    return out


def from_arrays(prefix: str, cls: type | None, data: dict[str, np.ndarray]) -> Any:
    """Rebuild what :func:`to_arrays` stored under ``prefix`` as an instance of ``cls``."""
    if prefix in data:
        v = data[prefix]
        if v.dtype.kind == "U" and v.shape == () and str(v) == _NONE:
            return None
        return _scalar(v)
    if cls is None or not dataclasses.is_dataclass(cls):
        raise KeyError(f"checkpoint has no {prefix!r}")
    hints = {f.name: f for f in dataclasses.fields(cls)}
    kwargs = {}
    for name, f in hints.items():
        key = f"{prefix}/{name}"
        has_default = (f.default is not dataclasses.MISSING
                       or f.default_factory is not dataclasses.MISSING)
        if has_default and not any(k == key or k.startswith(key + "/") for k in data):
            continue  # a field added after the checkpoint was written: its default
        sub = f.type if isinstance(f.type, type) else None
        nested = f.metadata.get("state_class") if f.metadata else None
        kwargs[name] = from_arrays(key, nested or sub, data)
    return cls(**kwargs)


def _scalar(v: np.ndarray) -> Any:
    """0-d arrays back to Python numbers/strings; others stay arrays."""
    if v.shape != ():
        return v
    if v.dtype.kind == "U":
        return str(v)
    if v.dtype.kind == "b":
        return bool(v)
    if v.dtype.kind in "iu":
        return int(v)
    return float(v)
