"""Property: any scenario made malformed from a bundled one ends `imc validate` in exit 2,
one line, naming the field as written (or the YAML line), within a time limit (issue 17).

Hypothesis draws a few hundred cases (derandomised: the same cases every run): a leaf of a
bundled scenario gets a value of the wrong kind (NaN, inf, 1e308, a 400-digit integer, text,
a list, a mapping, true / false), a mapping gets an unknown key, or the YAML text gets a
duplicate key, an explicit tag, deep nesting or an impossible date.
"""

from __future__ import annotations

import math
import tempfile
import time
from pathlib import Path

import yaml
from conftest import ROOT
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from imc.cli import app

runner = CliRunner()
BASES = {p.stem: yaml.safe_load(p.read_text()) for p in sorted((ROOT / "scenarios").glob("*.yaml"))}
TIME_LIMIT_S = 5.0


def _script():
    import importlib.util

    spec = importlib.util.spec_from_file_location("fuzz_inputs",
                                                  ROOT / "scripts" / "fuzz_inputs.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


_SCRIPT = _script()
_leaves, _set = _SCRIPT.leaves, _SCRIPT.set_at  # the fuzz script's tree walk


def _mappings(node, path=()):
    if isinstance(node, dict):
        yield path
        for k, v in node.items():
            yield from _mappings(v, path + (k,))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            yield from _mappings(v, path + (i,))


BAD_NUMBERS = [math.nan, math.inf, -math.inf, 1e308, -1e308, 10**400, "abc", "", [1.0],
               {"a": 1}, True, False]
BAD_OTHERS = [12345, 1.5, [1], {"a": 1}, None]
BAD_BOOLS = ["maybe", 7, [True], {"a": 1}]
LEAVES = [(name, path, v) for name, data in BASES.items() for path, v in _leaves(data)
          if path and (path != ("name",) or not isinstance(v, str))]
MAPPINGS = [(name, path) for name, data in BASES.items() for path in _mappings(data)]
TEXTS = [  # (appended YAML, the words the one line must hold)
    ("camera: {}\n", "duplicate key camera"),
    ("extra: !!float abc\n", "cannot read abc as float"),
    ("extra: !!python/object:os.system ls\n", "is not allowed"),
    ("extra: !local 3\n", "is not allowed"),
    ("extra: " + "[" * 400 + "]" * 400 + "\n", "nesting deeper"),
    ("extra: &r [*r]\n", "recursive alias"),
    ("extra: " + "9" * 5000 + "\n", "cannot read"),
]
DATES = [("2026-13-01", "month must be in 1..12"), ("2026-02-30", "day is out of range"),
         ("2300-01-01T00:00:00Z", "orbit.epoch_utc"), ("1500-06-01", "orbit.epoch_utc"),
         ("0", "orbit.epoch_utc")]


def _accepts_none(path) -> bool:
    """Whether the schema field at ``path`` (keys and list indices) takes null as a value
    (e.g. correlator.subpixel: null, the method's own default): then null is not malformed."""
    import types
    import typing

    from pydantic import BaseModel

    from imc.scenario import Scenario

    ann = Scenario
    for key in path:
        while typing.get_origin(ann) in (typing.Union, types.UnionType, typing.Annotated):
            args = [a for a in typing.get_args(ann) if a is not type(None)]
            ann = args[0]
        if isinstance(key, int):
            args = typing.get_args(ann)
            if not args:
                return False
            ann = args[0]
        elif isinstance(ann, type) and issubclass(ann, BaseModel) and key in ann.model_fields:
            ann = ann.model_fields[key].annotation
        else:
            return False
    return type(None) in typing.get_args(ann)


def _dotted(path) -> str:
    return ".".join(str(p) for p in path)


@st.composite
def malformed(draw):
    """(YAML text, words the error line must contain)."""
    kind = draw(st.sampled_from(["leaf"] * 6 + ["unknown"] * 2 + ["text", "date"]))
    if kind == "leaf":
        name, path, v = draw(st.sampled_from(LEAVES))
        data = yaml.safe_load(yaml.safe_dump(BASES[name], sort_keys=False))
        if isinstance(v, bool):
            new = draw(st.sampled_from(BAD_BOOLS))
        elif isinstance(v, int | float):
            new = draw(st.sampled_from(BAD_NUMBERS))
        else:
            new = draw(st.sampled_from(BAD_OTHERS))
            assume(new is not None or not _accepts_none(path))
        _set(data, path, new)
        return yaml.safe_dump(data, sort_keys=False), [_dotted(path)]
    if kind == "unknown":
        name, path = draw(st.sampled_from(MAPPINGS))
        data = yaml.safe_load(yaml.safe_dump(BASES[name], sort_keys=False))
        node = data
        for k in path:
            node = node[k]
        key = draw(st.sampled_from(["colour", "x_m", "typo_hz"]))
        node[key] = 1
        return yaml.safe_dump(data, sort_keys=False), [_dotted(path + (key,))]
    name = draw(st.sampled_from(sorted(BASES)))
    text = yaml.safe_dump(BASES[name], sort_keys=False)
    if kind == "text":
        extra, words = draw(st.sampled_from(TEXTS))
        line = len(text.splitlines()) + 1
        return text + extra, [words, f"line {line}"]
    date, words = draw(st.sampled_from(DATES))
    data = yaml.safe_load(text)
    data.setdefault("orbit", {})["epoch_utc"] = "@DATE@"
    return yaml.safe_dump(data, sort_keys=False).replace("'@DATE@'", date), [words]


@settings(max_examples=300, deadline=None, derandomize=True, database=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(case=malformed())
def test_malformed_scenarios_end_validate_in_one_line_naming_the_field(case):
    text, words = case
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "fuzzed.yaml"
        p.write_text(text)
        t = time.perf_counter()
        res = runner.invoke(app, ["validate", str(p)])
        wall = time.perf_counter() - t
    out = res.output.strip()
    assert res.exception is None or isinstance(res.exception, SystemExit), out
    assert res.exit_code == 2, out
    assert len(out.splitlines()) == 1 and out.startswith("error:"), out
    assert "Traceback" not in out and len(out) < 700, out
    for w in words:
        assert w in out, (w, out)
    assert wall < TIME_LIMIT_S, (wall, out)
