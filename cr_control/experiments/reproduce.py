"""``cr_reproduce [--quick] --out DIR``: thesis runs as sweeps on Ray, claims with computed
verdicts, one self-contained HTML report.

Covered so far: chapter 3 (the three impedance schemes on the compliant plane, with the
robustness map: RMS error against K_e x0.1 ... x10 and, in the full run, link-mass error),
chapter 5 (fixed impedance and fuzzy unidirectional control, with the map of separation
against disturbance size and duration), and chapters 2, 4, 6 and appendix C
(:mod:`.chapters_246c`: maps of settling and error against k_o, k_s and of the error
against K_s for both chapter 6 schemes).

Every study is a :func:`cr_control.experiments.sweep.sweep` (so resumable: DIR/runs/<study>/),
every figure is the sweep's own, inlined as base64 PNG. ``claims.json``: one entry per claim,
``{"chapter", "claim", "measured", "rule", "verdict"}``; the verdict is computed from the
measured numbers by the rule written next to it (reproduced / not reproduced; "reproduced
with correction" where the claim names the thesis correction its run needs: docs/thesis.md),
never typed.
"""

from __future__ import annotations

import argparse
import base64
import html
import json
import math
import sys
import time
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

from cr_control.experiments import (
    chapters_246c,
    engine,
    normalised_gradient,
    panda_map,
    results_tables,
)
from cr_control.experiments.spec import SpecError, parse_spec
from cr_control.experiments.study import Study, row
from cr_control.experiments.sweep import SweepResult, sweep

CH3 = {"adaptive_impedance": "3.5.1", "robust_adaptive_impedance": "3.5.2",
       "nn_adaptive_impedance": "3.5.3"}
CH3_STIFFNESS = {"quick": [15.0, 150.0, 1500.0], "full": [15.0, 47.4, 150.0, 474.0, 1500.0]}
CH3_MASS = {"quick": [[0.1, 0.1]], "full": [[0.05, 0.05], [0.1, 0.1], [0.15, 0.15]]}
CH5 = ("impedance", "fuzzy_unidirectional")
CH5_MAGNITUDE = {"quick": [2.0, 6.3, 8.0], "full": [2.0, 4.0, 6.0, 6.2, 6.4, 6.6, 7.0, 8.0, 10.0]}
CH5_DURATION = {"quick": [0.06, 0.2], "full": [0.06, 0.1, 0.2]}
CH5_SECONDS = {"quick": 4.0, "full": 10.0}
#: Chapter 3's verdict: the force error is "bounded" if it stays below this (N).
FORCE_BOUND_N = 10.0
ROOT = Path(__file__).resolve().parents[2]
#: Modules adding studies and claims, each with ``studies(mode)`` and ``claims(results)``.
MODULES = (normalised_gradient, panda_map)


def studies(mode: str) -> list[Study]:
    """The sweeps of ``mode`` (quick / full)."""
    out = []
    for scheme, section in CH3.items():
        vary: dict[str, Any] = {"plant.stiffness": CH3_STIFFNESS[mode]}
        if len(CH3_MASS[mode]) > 1:
            vary["plant.link_mass"] = CH3_MASS[mode]
        out.append(Study(f"ch3_{scheme}", "3", f"{scheme} ({section}): RMS position error 5-10 s "
                         "against K_e (thesis 150 N/m) and link mass (thesis 0.1 kg)",
                         {"scheme": scheme, "duration": 10.0, "vary": vary,
                          "metrics": ["pos_err_rms_last_half_m", "pos_err_rms_m",
                                      "f_err_x_max_N", "f_err_x_min_N", "contact_lost_s"]}))
    for scheme in CH5:
        out.append(Study(f"ch5_{scheme}", "5", f"{scheme}: time separated from the surface "
                         "against the push-off disturbance (thesis 2 N, 0.06 s)",
                         {"scheme": scheme, "duration": CH5_SECONDS[mode],
                          "vary": {"plant.disturbance_magnitude": CH5_MAGNITUDE[mode],
                                   "plant.disturbance_duration": CH5_DURATION[mode]},
                          "metrics": ["separated_s", "f_m_min_after_N", "f_err_rms_after_N",
                                      "pos_err_rms_after_m"]}))
    out += chapters_246c.studies(mode)
    for module in MODULES:
        out += module.studies(mode)
    return out


def claims(results: dict[str, SweepResult]) -> list[dict[str, Any]]:
    """Every claim with its measured numbers, rule and computed verdict."""
    out = []

    def claim(chapter: str, text: str, measured: dict[str, Any], rule: str,
              holds: Callable[[], bool], correction: str = "") -> None:
        """One claim; ``correction``: the thesis defect (docs/thesis.md, equation numbers) the run
        corrects, if any: the verdict is then "reproduced with correction" when it holds."""
        verdict = ("reproduced with correction" if correction else "reproduced") if holds() \
            else "not reproduced"
        entry = {"chapter": chapter, "claim": text, "measured": measured, "rule": rule,
                 "verdict": verdict}
        if correction:
            entry["correction"] = correction
        out.append(entry)

    for scheme, section in CH3.items():
        result = results[f"ch3_{scheme}"]
        thesis_point: dict[str, Any] = {"plant__stiffness": 150.0}
        if result.rows and "plant.link_mass" in result.rows[0]:
            thesis_point["plant__link_mass"] = [0.1, 0.1]
        r = row(result, **thesis_point)
        f_err = max(abs(r["f_err_x_max_N"]), abs(r["f_err_x_min_N"]))
        claim("3", f"{section}: {scheme} keeps contact with the plane, the force error stays "
              "bounded and the position error decreases (sec. 3.5, thesis gains, K_e = 150 N/m)",
              {"pos_err_rms_5_10s_mm": 1e3 * r["pos_err_rms_last_half_m"],
               "pos_err_rms_0_10s_mm": 1e3 * r["pos_err_rms_m"],
               "force_err_max_N": f_err, "contact_lost_s": r["contact_lost_s"],
               "status": r["status"]},
              f"status ok, contact_lost_s = 0, max |f_d,x - f_x| < {FORCE_BOUND_N:g} N and RMS "
              "error over 5-10 s below that over 0-10 s",
              lambda r=r, f_err=f_err: r["status"] == "ok" and r["contact_lost_s"] == 0.0
              and f_err < FORCE_BOUND_N and r["pos_err_rms_last_half_m"] < r["pos_err_rms_m"])
    thesis = {"plant__disturbance_magnitude": 2.0, "plant__disturbance_duration": 0.06}
    fixed, fuzzy = (row(results[f"ch5_{s}"], **thesis) for s in CH5)
    claim("5", "5.4: \"fixed impedance loses contact after the disturbance\" (2 N, 0.06 s)",
          {"separated_s": fixed["separated_s"], "f_m_min_after_N": fixed["f_m_min_after_N"]},
          "fixed impedance's separated_s > 0 under the thesis disturbance",
          lambda: fixed["separated_s"] > 0.0)
    claim("5", "5.4: the fuzzy unidirectional controller keeps contact under the same "
          "disturbance", {"separated_s": fuzzy["separated_s"],
                          "f_m_min_after_N": fuzzy["f_m_min_after_N"]},
          "fuzzy's separated_s = 0 under the thesis disturbance",
          lambda: fuzzy["separated_s"] == 0.0)

    def threshold(scheme: str) -> float:
        lost = [r["plant.disturbance_magnitude"] for r in results[f"ch5_{scheme}"].rows
                if r["plant.disturbance_duration"] == 0.06 and r["separated_s"] > 0.0]
        return min(lost) if lost else math.inf

    a, b = threshold("impedance"), threshold("fuzzy_unidirectional")

    def shown(x: float) -> Any:
        return x if math.isfinite(x) else "none in the grid"

    claim("5", "5.4: fuzzy unidirectional control tolerates larger push-off disturbances than "
          "fixed impedance", {"separating_magnitude_fixed_N": shown(a),
                              "separating_magnitude_fuzzy_N": shown(b),
                              "grid_N": sorted({r["plant.disturbance_magnitude"]
                                                for r in results["ch5_impedance"].rows})},
          "the smallest 60 ms disturbance of the grid that separates is larger for fuzzy",
          lambda: b > a)
    chapters_246c.claims(results, claim)
    for module in MODULES:
        out += module.claims(results)
    return out


def _defects() -> str:
    """The thesis defects section of docs/thesis.md as HTML (lists and their headings)."""
    path = ROOT / "docs" / "thesis.md"
    if not path.exists():
        return "<p>docs/thesis.md not found.</p>"
    lines = path.read_text().splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("## Thesis defects"))
    body, items, current = [], [], None
    for line in lines[start + 1:]:
        if line.startswith("## "):
            break
        if line.startswith("- "):
            current = line[2:]
            items.append(current)
        elif line.startswith("  ") and items:
            items[-1] += " " + line.strip()
        elif line.strip():
            if items:
                body.append("<ul>" + "".join(f"<li>{html.escape(i)}</li>" for i in items) + "</ul>")
                items = []
            body.append(f"<h4>{html.escape(line.strip())}</h4>")
    if items:
        body.append("<ul>" + "".join(f"<li>{html.escape(i)}</li>" for i in items) + "</ul>")
    return "\n".join(body)


def _format(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:.4g}"
    return html.escape(str(value))


def report(out: Path, mode: str, results: dict[str, SweepResult], items: list[dict[str, Any]],
           all_studies: list[Study], seconds: float) -> Path:
    """DIR/report.html: per chapter the claims table and the sweeps' figures, inline."""
    parts = [f"<h1>cr_control: the thesis reproduced ({mode})</h1>",
             f"<p>{sum(len(r.rows) for r in results.values())} offline runs on Ray in "
             f"{seconds:.0f} s. Verdicts are computed by the rule in each row.</p>"]
    for chapter in sorted({s.chapter for s in all_studies}):
        parts.append(f"<h2>{'Appendix' if chapter == 'C' else 'Chapter'} {chapter}</h2>"
                     "<table border=1 cellpadding=4>"
                     "<tr><th>claim</th><th>measured</th><th>rule</th><th>verdict</th></tr>")
        for c in (c for c in items if c["chapter"] == chapter):
            measured = "<br>".join(f"{k} = {_format(v)}" for k, v in c["measured"].items())
            parts.append(f"<tr><td>{html.escape(c['claim'])}</td><td>{measured}</td>"
                         f"<td>{html.escape(c['rule'])}</td><td><b>{c['verdict']}</b>"
                         + (f"<br>{html.escape(c['correction'])}" if "correction" in c else "")
                         + "</td></tr>")
        parts.append("</table>")
        for study in (s for s in all_studies if s.chapter == chapter):
            parts.append(f"<h3>{html.escape(study.title)}</h3>")
            for figure in results[study.name].figures:
                data = base64.b64encode(figure.read_bytes()).decode()
                parts.append(f'<img alt="{html.escape(figure.stem)}" '
                             f'src="data:image/png;base64,{data}">')
    parts.append("<h2>Thesis defects (docs/thesis.md)</h2>" + _defects())
    path = out / "report.html"
    path.write_text("<!DOCTYPE html><html><head><meta charset='utf-8'><title>cr_reproduce"
                    "</title></head><body>" + "\n".join(parts) + "</body></html>\n")
    return path


def main(argv: Iterable[str] | None = None) -> int:
    """Entry point of ``cr_reproduce``; returns the exit status."""
    parser = argparse.ArgumentParser(prog="cr_reproduce", description="Run the thesis studies "
                                     "on Ray; write report.html and claims.json.")
    parser.add_argument("--out", type=Path, required=True, metavar="DIR")
    parser.add_argument("--quick", action="store_true", help="coarser maps, shorter ch. 4, 5 and C runs")
    parser.add_argument("--address", metavar="HOST:PORT", help="join this Ray cluster")
    parser.add_argument("--write-tables", type=Path, metavar="RESULTS.md", help="then write "
                        "the claims tables into this file (docs/results.md)")
    args = parser.parse_args(None if argv is None else list(argv))
    mode = "quick" if args.quick else "full"
    start = time.monotonic()
    results: dict[str, SweepResult] = {}
    all_studies = studies(mode)
    try:
        for study in all_studies:
            spec, targets = parse_spec(study.spec, study.name)
            print(f"{study.name}:", file=sys.stderr)
            results[study.name] = sweep(spec, targets, args.out / "runs" / study.name,
                                        args.address)
    except (SpecError, engine.EngineError) as exc:
        print(f"cr_reproduce: error: {exc}", file=sys.stderr)
        return 1
    finally:
        engine.stop()
    items = claims(results)
    (args.out / "claims.json").write_text(json.dumps(items, indent=2, default=str) + "\n")
    path = report(args.out, mode, results, items, all_studies, time.monotonic() - start)
    for c in items:
        print(f"ch. {c['chapter']}: {c['verdict']:15s} {c['claim'][:80]}")
    print(f"wrote {path} and {args.out / 'claims.json'} in {time.monotonic() - start:.0f} s")
    if args.write_tables:
        return results_tables.main([str(args.out / "claims.json"), "--write",
                                    str(args.write_tables)])
    return 0


if __name__ == "__main__":
    sys.exit(main())
