"""Write docs/scenario.md from the pydantic schema in imc/scenario.py (run: make docs)."""

from __future__ import annotations

import dataclasses
import sys
import typing
from pathlib import Path

from pydantic import BaseModel

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from imc.scenario import BlockConfig, Scenario, _Model  # noqa: E402

HEADER = """# Scenario reference

A scenario is one YAML file; every field is optional (defaults below are IKONOS-like) and
unknown fields are errors. `imc validate FILE` checks a file and its geometry without
rendering. This page is generated from `imc/scenario.py` by `scripts/gen_scenario_doc.py`
(`tests/test_scenario_cli.py` fails when it is stale).
"""


def _model_of(annotation) -> type[BaseModel] | None:
    """The model a field holds directly (section) or as tuple items (list)."""
    if isinstance(annotation, type) and issubclass(annotation, _Model):
        return annotation
    for arg in typing.get_args(annotation):
        if isinstance(arg, type) and issubclass(arg, _Model):
            return arg
    return None


def _default(field) -> str:
    if field.is_required():
        return "(required)"
    d = field.default
    if isinstance(d, BaseModel):
        return "see below"
    if d is None:
        return ""
    if isinstance(d, tuple) and d and isinstance(d[0], BaseModel):
        return f"{len(d)} items"
    return repr(d) if isinstance(d, str) else str(d)


def sections(model: type[BaseModel], prefix: str, out: list[str], title: str) -> None:
    doc = (model.__doc__ or "").strip()
    rows, nested = [], []
    for name, field in model.model_fields.items():
        sub = _model_of(field.annotation)
        path = f"{prefix}{name}"
        is_list = typing.get_origin(field.annotation) is tuple
        if sub is not None and isinstance(field.default, BaseModel | type(None)) and not is_list:
            nested.append((sub, f"{path}.", path))
            rows.append(f"| `{path}` | see below | {field.description or ''} |")
            continue
        if sub is not None and typing.get_origin(field.annotation) is dict:
            nested.append((sub, f"{path}.<metric path>.", f"{path} bounds"))
        elif sub is not None:
            nested.append((sub, f"{path}[].", f"{path} items"))
        rows.append(f"| `{path}` | {_default(field)} | {field.description or ''} |")
    out.append(f"## {title}\n")
    if doc and not doc.startswith("!") and model is not Scenario:
        out.append(" ".join(doc.split()) + "\n")
    out.append("| field | default | meaning |\n|---|---|---|")
    out.extend(rows)
    out.append("")
    if issubclass(model, BlockConfig):
        block_kinds(model, prefix, out)
    for sub, p, t in nested:
        sections(sub, p, out, t)


def _value(v) -> str:
    if v is dataclasses.MISSING:
        return "(required)"
    if v is None:
        return "none (see text)"
    return repr(v) if isinstance(v, str) else str(v)


def block_kinds(model: type[BlockConfig], prefix: str, out: list[str]) -> None:
    """The kinds registered for a block role and their parameters (from the classes)."""
    from compensation.registry import block_class, kinds

    for kind in kinds(model.ROLE):
        cls = block_class(model.ROLE, kind)
        wired = set(getattr(cls, "WIRED", ()))
        doc = " ".join((cls.__doc__ or "").split())
        out.append(f"### `{prefix}kind: {kind}`\n")
        out.append(doc + "\n")
        rows = []
        for f in dataclasses.fields(cls):
            if not f.init or f.name in wired or callable(f.default) and f.name == "nominal_px":
                continue
            default = f.default if f.default_factory is dataclasses.MISSING else f.default_factory()
            rows.append(f"| `{prefix}{f.name}` | {_value(default)} |")
        if rows:
            out.append("| parameter | default |\n|---|---|")
            out.extend(rows)
        for opt in model.OPTIONS:
            if opt == "feedforward" and kind == "kalman":
                out.append(f"| `{prefix}feedforward` | False |")
        out.append("")


def render() -> str:
    out = [HEADER]
    sections(Scenario, "", out, "(top level)")
    return "\n".join(out).rstrip() + "\n"


if __name__ == "__main__":
    (ROOT / "docs" / "scenario.md").write_text(render(), encoding="utf-8")
    print("wrote docs/scenario.md")
