"""Expectations: a scenario's ``expect:`` bounds judged on a run's metrics, and JUnit XML.

A metric path is dotted into metrics.json (``with_compensation.rms_total_px``); an integer
part indexes a list (``tracker.rms_error_px.0`` is the row). A bound on a whole list must hold
for every element. A path that names nothing, or a value that is not a number, fails.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

from imc.io import atomic_write
from imc.scenario import BoundConfig


class MetricPathError(KeyError):
    """A metric path that names nothing in metrics.json."""


def lookup(metrics: Mapping, path: str):
    """The value at a dotted path of a metrics mapping (ints index lists)."""
    node = metrics
    done: list[str] = []
    for part in path.split("."):
        if isinstance(node, Mapping):
            if part not in node:
                where = ".".join(done) or "metrics.json"
                keys = ", ".join(map(str, node)) or "nothing"
                raise MetricPathError(f"{where} has no {part!r} (it has {keys})")
            node = node[part]
        elif isinstance(node, Sequence) and not isinstance(node, str):
            if not part.lstrip("-").isdigit() or not -len(node) <= int(part) < len(node):
                raise MetricPathError(f"{'.'.join(done)} is a list of {len(node)}; index it "
                                      f"with 0..{len(node) - 1}, not {part!r}")
            node = node[int(part)]
        else:
            raise MetricPathError(f"{'.'.join(done)} is a value ({node!r}), it has no "
                                  f"{part!r}")
        done.append(part)
    return node


@dataclass(frozen=True)
class Outcome:
    """One expectation judged: its path, bound, the value found, and whether it holds."""

    path: str
    bound: str
    value: str
    passed: bool
    note: str = ""

    def line(self) -> str:
        verdict = "pass" if self.passed else "FAIL"
        return (f"{verdict}  {self.path} = {self.value} (expected {self.bound})"
                + (f": {self.note}" if self.note else ""))


def _numbers(value) -> list[float] | None:
    vals = value if isinstance(value, list | tuple) else [value]
    if not vals or any(isinstance(v, bool) or not isinstance(v, int | float | type(None))
                       for v in vals):
        return None
    return [math.nan if v is None else float(v) for v in vals]


def judge(expect: Mapping[str, BoundConfig], metrics: Mapping) -> list[Outcome]:
    """Every expectation against the metrics, in the order written."""
    out = []
    for path, bound in expect.items():
        try:
            value = lookup(metrics, path)
        except MetricPathError as e:
            out.append(Outcome(path, bound.text(), "missing", False, str(e).strip('"')))
            continue
        nums = _numbers(value)
        if nums is None:
            out.append(Outcome(path, bound.text(), repr(value), False, "not a number"))
            continue
        lo, hi = bound.lo_hi
        ok = all(lo <= v <= hi for v in nums)  # NaN (None) never passes
        shown = ", ".join(f"{v:.5g}" for v in nums)
        out.append(Outcome(path, bound.text(), f"[{shown}]" if len(nums) > 1 else shown, ok,
                           "" if ok or not any(map(math.isnan, nums)) else "no value (NaN)"))
    return out


@dataclass(frozen=True)
class CaseResult:
    """One scenario of `imc check`: its outcomes, or the one-line error that stopped it."""

    name: str
    source: str
    time_s: float
    outcomes: tuple[Outcome, ...] = ()
    error: str | None = None

    @property
    def passed(self) -> bool:
        return self.error is None and all(o.passed for o in self.outcomes)


def write_junit(path: Path, cases: Sequence[CaseResult], suite: str = "imc check") -> None:
    """JUnit XML (one testcase per scenario; failures list the expectations that failed,
    errors the run's one-line error), written atomically."""
    failures = sum(c.error is None and not c.passed for c in cases)
    errors = sum(c.error is not None for c in cases)
    total_s = sum(c.time_s for c in cases)
    root = ET.Element("testsuites", name=suite, tests=str(len(cases)), failures=str(failures),
                      errors=str(errors), time=f"{total_s:.3f}")
    ts = ET.SubElement(root, "testsuite", name=suite, tests=str(len(cases)),
                       failures=str(failures), errors=str(errors), time=f"{total_s:.3f}")
    for c in cases:
        tc = ET.SubElement(ts, "testcase", classname=Path(c.source).parent.as_posix()
                           .replace("/", ".") or "scenarios", name=c.name,
                           file=c.source, time=f"{c.time_s:.3f}")
        if c.error is not None:
            ET.SubElement(tc, "error", message=c.error, type="RunError").text = c.error
        elif not c.passed:
            bad = [o for o in c.outcomes if not o.passed]
            ET.SubElement(tc, "failure", message="; ".join(o.line() for o in bad),
                          type="ExpectationFailed").text = "\n".join(o.line() for o in bad)
        if c.outcomes:
            ET.SubElement(tc, "system-out").text = "\n".join(o.line() for o in c.outcomes)
    ET.indent(root)
    atomic_write(Path(path), lambda p: ET.ElementTree(root).write(
        p, encoding="utf-8", xml_declaration=True))


def check_one(path: str, out_dir: str, report: bool = False) -> dict:
    """Run one scenario (on a worker) and judge its expectations: a plain dict for the
    client (name, source, time_s, outcomes or error). Writes expectations.json beside the
    run's metrics (and report.html with ``report``)."""
    import dataclasses
    import time

    from imc.io import write_json
    from imc.outputs.htmlreport import EXPECTATIONS, write_run_report
    from imc.pipeline import run_scenario
    from imc.scenario import error_line, load_scenario

    t0 = time.perf_counter()
    name = Path(path).stem
    try:
        sc = load_scenario(path)
        name = sc.name
        metrics, _ = run_scenario(sc, Path(out_dir), rerun=False)
    except Exception as e:  # a scenario that cannot run is this test case's error
        return {"name": name, "source": path, "time_s": time.perf_counter() - t0,
                "error": error_line(e)}
    outcomes = [dataclasses.asdict(o) for o in judge(sc.expect, metrics)]
    write_json(Path(out_dir) / EXPECTATIONS, outcomes)
    if report:
        write_run_report(Path(out_dir))
    return {"name": sc.name, "source": path, "time_s": time.perf_counter() - t0,
            "outcomes": outcomes}
