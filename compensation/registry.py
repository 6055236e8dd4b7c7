"""The loop blocks' factory: the registry (kind -> class, per role) and the checks of a
block's parameters as a scenario writes them.

Importing this module imports the built-in kinds (each registers itself with
:func:`compensation.blocks.register`); adding a kind is one class in any module imported
before :func:`make_block` is called: its dataclass fields are its parameters (checked by
:func:`check_params` with pydantic: unknown names, true / false for numbers, NaN and
out-of-range numbers, each error naming the parameter), ``WIRED`` names the ones the wiring
derives from the rest of a scenario, and a controller's ``TUNING`` names the parameter that
sets its gain (for the wiring's stability-margin messages).
"""

from __future__ import annotations

import dataclasses
import typing
from functools import cache
from typing import Any

import numpy as np
from pydantic import TypeAdapter, ValidationError

import compensation.actuators  # noqa: F401  (registers the actuator kinds)
import compensation.controllers  # noqa: F401  (registers the controller kinds)
import compensation.estimators  # noqa: F401  (registers the estimator kinds)
import compensation.supervisor  # noqa: F401  (registers the supervisor kinds)
from compensation.blocks import REGISTRY

#: largest magnitude of any number in a scenario (products of a few stay far from overflow)
MAX_MAGNITUDE = 1e12


def kinds(role: str) -> tuple[str, ...]:
    """The registered kinds of a role ('estimator', 'controller', 'actuator', 'supervisor')."""
    return tuple(sorted(REGISTRY[role]))


def block_class(role: str, kind: str) -> type:
    """The class registered as ``kind`` for ``role``; a clear ValueError otherwise."""
    try:
        return REGISTRY[role][kind]
    except KeyError:
        raise ValueError(f"unknown {role} kind {kind!r}; choose one of {kinds(role)}") from None


def build(role: str, kind: str, **params) -> Any:
    """An instance of the registered ``kind`` for ``role``.

    A class may name ``WIRED`` parameters: the ones the wiring derives from the rest of a
    scenario (rates, the field point), which a scenario may not set.
    """
    return block_class(role, kind)(**params)


# ------------------------------------------------------------------ parameter checks


def short(value: object, limit: int = 60) -> str:
    """``repr(value)`` cut to about ``limit`` characters (middle elided), on one line."""
    text = value if isinstance(value, str) else repr(value)
    text = " ".join(str(text).split())
    if len(text) <= limit:
        return text
    keep = max(8, (limit - 5) // 2)
    return f"{text[:keep]} ... {text[-keep:]} ({len(text)} characters)"


def expects_number(annotation) -> bool:
    """True if a field's type is int or float (optional, annotated or in a tuple)."""
    if annotation in (int, float):
        return True
    return any(expects_number(a) for a in typing.get_args(annotation)
               if isinstance(a, type) or typing.get_args(a))


def bool_at(value) -> int | None:
    """Index of the first true / false in ``value`` (a list or tuple, or 0 for a bare
    bool); None when there is none."""
    items = value if isinstance(value, list | tuple) else (value,)
    return next((i for i, x in enumerate(items) if isinstance(x, bool)), None)


def make_block(role: str, kind: str, params: dict, wired: dict | None = None):
    """The block ``kind`` of ``role`` built from a scenario's parameters (validated and
    converted by pydantic, nested dataclasses included) plus those of the ``wired`` values
    (what the wiring derives from the rest of the scenario: rates, the field point) that the
    class names in its ``WIRED``."""
    check_params(role, kind, params)
    cls = block_class(role, kind)
    names = getattr(cls, "WIRED", ())
    given = {k: v for k, v in (wired or {}).items() if k in names}
    return _adapter(cls).validate_python({**params, **given})


@cache
def _adapter(cls):
    """pydantic's validator of a block class, built once (building it costs ~5 ms)."""
    return TypeAdapter(cls)


def _bad_number(value, path: str = "") -> tuple[str, object] | None:
    """(path, value) of the first NaN, inf or too-large float inside a parameter value."""
    if isinstance(value, float) and not abs(value) <= MAX_MAGNITUDE:
        return path, value
    if isinstance(value, list | tuple):
        items = enumerate(value)
    elif isinstance(value, dict):
        items = value.items()
    else:
        return None
    for k, v in items:
        bad = _bad_number(v, f"{path}.{k}")
        if bad is not None:
            return bad
    return None


def _nested_problem(hint, value, path: str) -> tuple[str, str] | None:
    """(dotted path, message) of the first key of ``value`` that a nested dataclass of
    ``hint`` (itself, a list / tuple of it, optional) does not have, or of a true / false
    given for one of its numbers; None when all is well."""
    if isinstance(value, dict):
        cls = next((a for a in (hint, *typing.get_args(hint)) if dataclasses.is_dataclass(a)),
                   None)
        if cls is None:
            return None
        names = {f.name for f in dataclasses.fields(cls) if f.init}
        try:
            hints = typing.get_type_hints(cls)
        except Exception:  # noqa: BLE001 (an unresolvable hint: check the keys only)
            hints = {}
        for k, v in value.items():
            if k not in names:
                return (f"{path}.{short(str(k), 40)}",
                        "unknown parameter (check the spelling; see docs/scenario.md)")
            if isinstance(v, bool) and expects_number(hints.get(k)):
                return f"{path}.{k}", "give a number, not true / false"
            bad = _nested_problem(hints.get(k), v, f"{path}.{k}")
            if bad is not None:
                return bad
        return None
    if isinstance(value, list | tuple):
        args = [a for a in typing.get_args(hint) if a is not Ellipsis]
        inner = next((a for a in args if dataclasses.is_dataclass(a)), None)
        if inner is None:  # Optional[tuple[Line, ...]]: one level down
            inner = next((b for a in args for b in typing.get_args(a)
                          if dataclasses.is_dataclass(b)), None)
        for i, v in enumerate(value):
            bad = _nested_problem(inner, v, f"{path}.{i}")
            if bad is not None:
                return bad
    return None


def check_params(role: str, kind: str, params: dict) -> None:
    """Validate a block's parameters against its class (pydantic on the dataclass); a
    ValueError '@field@ message' names the offending parameter."""
    try:
        cls = block_class(role, kind)
    except ValueError:
        raise ValueError(f"@kind@ unknown {role} kind {kind!r}; choose one of "
                         f"{', '.join(kinds(role))}") from None
    wired = getattr(cls, "WIRED", ())
    names = {f.name for f in dataclasses.fields(cls) if f.init}
    try:
        hints = typing.get_type_hints(cls)
    except Exception:  # noqa: BLE001 (an unresolvable hint: no bool check for that class)
        hints = {}
    for key, value in params.items():
        if key in wired:
            raise ValueError(f"@{key}@ is set by imcsim from the rest of the scenario; "
                             "leave it out")
        if key not in names:
            allowed = ", ".join(sorted(names - set(wired)))
            raise ValueError(f"@{short(key, 40)}@ unknown parameter of {role} kind {kind!r} "
                             f"(allowed: {allowed})")
        if expects_number(hints.get(key)):
            at = bool_at(value)
            if at is not None:
                where = f"{key}.{at}" if isinstance(value, list | tuple) else key
                raise ValueError(f"@{where}@ give a number, not true / false")
        nested = _nested_problem(hints.get(key), value, key)
        if nested is not None:
            raise ValueError(f"@{nested[0]}@ {nested[1]}")
        bad = _bad_number(value)
        if bad is not None:
            raise ValueError(f"@{key}{bad[0]}@ must be a finite number of magnitude <= "
                             f"{MAX_MAGNITUDE:g} (got {short(bad[1])})")
    try:
        block = _adapter(cls).validate_python(dict(params))
    except ValidationError as e:
        err = e.errors()[0]
        msg = err["msg"].removeprefix("Value error, ")
        first = msg.split(" ", 1)[0]
        name = ".".join(str(p) for p in err["loc"]) or (first if first in names else "kind")
        raise ValueError(f"@{name}@ {msg}") from None
    for key in params:  # text such as "1e400" becomes inf in pydantic's lax mode
        value = getattr(block, key, None)
        if dataclasses.is_dataclass(value) and not isinstance(value, type):
            value = dataclasses.asdict(value)
        elif isinstance(value, list | tuple):
            value = [dataclasses.asdict(v) if dataclasses.is_dataclass(v) else v for v in value]
        elif isinstance(value, np.ndarray):
            value = value.tolist()
        bad = _bad_number(value)
        if bad is not None:
            raise ValueError(f"@{key}{bad[0]}@ must be a finite number of magnitude <= "
                             f"{MAX_MAGNITUDE:g} (got {short(params[key])})")
