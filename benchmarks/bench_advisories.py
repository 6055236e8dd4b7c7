"""Never worse than open, or said: every bundled scenario as it is, with its correlator device
switched on, and with its main imager started at 0.1 s; for each, the main-imager exposures
the loop made worse than open loop, and the warnings imcsim gave before the run.

    .venv/bin/python benchmarks/bench_advisories.py [--out benchmarks/out/advisories]

On the analytic plant (the tracker's predicted errors; the question is the loop's, and a
rendered pass of 27 runs would take an hour): ~8 minutes on 2 cores. Writes advisories.json
and advisories.md (quoted in docs/loop-targets.md). A row passes when no exposure is worse or
a warning said why before the run.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from imc.io import write_json  # noqa: E402
from imc.pipeline import run_scenario  # noqa: E402
from imc.scenario import ScenarioError, parse_scenario  # noqa: E402
from imc.yamlload import with_changes  # noqa: E402

VARIANTS = {
    "as bundled": {},
    "device on": {"correlator.timing.enabled": True},
    "imager from 0.1 s": {"camera.main_imager.start_s": 0.1},
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "out" / "advisories"))
    a = ap.parse_args()
    out = Path(a.out)
    rows, results = [], []
    for f in sorted((ROOT / "scenarios").glob("*.yaml")):
        for label, changes in VARIANTS.items():
            data = with_changes(yaml.safe_load(f.read_text()), {
                "plant.fidelity": "analytic", "metrics.blur_images": False,
                "product.enabled": False, **changes})
            data.pop("expect", None)
            if not data.get("compensation", {}).get("enabled", True):
                rows.append(f"| {f.stem} | {label} | no loop (compensation.enabled: false) "
                            "| | yes |")
                continue
            warnings: list[str] = []
            try:
                m, _ = run_scenario(parse_scenario(data, f.name), out / f"{f.stem}_{label}",
                                    rerun=False, fresh=True, warn=warnings.append)
            except ScenarioError as e:
                rows.append(f"| {f.stem} | {label} | refused: {e} | | |")
                results.append({"scenario": f.stem, "variant": label, "refused": str(e)})
                continue
            ex = m["exposures"]
            worse = ex["worse_than_open"] if m["compensation_enabled"] else 0
            said = [w.split(":")[0] for w in warnings]
            ok = worse == 0 or bool(warnings)
            rows.append(f"| {f.stem} | {label} | {worse} of {ex['n']} | "
                        f"{', '.join(said) or '-'} | {'yes' if ok else 'NO'} |")
            results.append({"scenario": f.stem, "variant": label, "worse": worse,
                            "exposures": ex["n"], "warnings": warnings, "ok": ok,
                            "rms_reduction": m["rms_reduction"]})
            print(rows[-1], flush=True)
    md = ("| scenario | variant | exposures worse than open | warned before the run | "
          "never worse, or said |\n|---|---|---|---|---|\n" + "\n".join(rows) + "\n")
    out.mkdir(parents=True, exist_ok=True)
    (out / "advisories.md").write_text(md)
    write_json(out / "advisories.json", results)
    print(md)


if __name__ == "__main__":
    main()
