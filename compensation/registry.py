"""The registry of the loop's blocks: kind -> class, per role.

Importing this module imports the built-in kinds (each registers itself with
:func:`compensation.blocks.register`); adding a kind is one class in any module imported
before :func:`build` is called.
"""

from __future__ import annotations

from typing import Any

import compensation.actuators  # noqa: F401  (registers the actuator kinds)
import compensation.controllers  # noqa: F401  (registers the controller kinds)
import compensation.estimators  # noqa: F401  (registers the estimator kinds)
import compensation.supervisor  # noqa: F401  (registers the supervisor kinds)
from compensation.blocks import _REGISTRY


def kinds(role: str) -> tuple[str, ...]:
    """The registered kinds of a role ('estimator', 'controller', 'actuator', 'supervisor')."""
    return tuple(sorted(_REGISTRY[role]))


def block_class(role: str, kind: str) -> type:
    """The class registered as ``kind`` for ``role``; a clear ValueError otherwise."""
    try:
        return _REGISTRY[role][kind]
    except KeyError:
        raise ValueError(f"unknown {role} kind {kind!r}; choose one of {kinds(role)}") from None


def build(role: str, kind: str, **params) -> Any:
    """An instance of the registered ``kind`` for ``role``.

    A class may name ``WIRED`` parameters: the ones the wiring derives from the rest of a
    scenario (rates, the field point), which a scenario may not set.
    """
    return block_class(role, kind)(**params)
