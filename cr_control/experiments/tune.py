"""``cr_tune SPEC.yaml --out DIR [--address ADDR]``: search a scheme's live gains on Ray Tune.

SPEC (YAML)::

    scheme: adaptive_impedance
    duration: 10.0                      # simulated seconds per trial
    metric: pos_err_rms_last_half_m     # minimised (a name cr_analyze prints)
    search:                             # live gains of the scheme: ranges as cr_sweep's
      adaptive_impedance.Q_c: {low: 0.5, high: 500, log: true}
    samples: 40                         # trials of the first round
    seed: 0
    set: {}                             # the tuning scenario (overrides), optional
    scenarios: [{}, {plant.stiffness: 600.0}]   # optional: tune on the worst of these
    held_out: {plant.stiffness: 300.0}  # the validation scenario: another K_e or payload

Search: Ray Tune, two rounds of seeded random search (``BasicVariantGenerator``): ``samples``
trials over the ranges, then ``samples // 2`` in ranges narrowed around the best (a factor
NARROW either way on a log range, a quarter of the range on a linear one). A trial runs
each of ``scenarios`` (overrides on top of ``set``; default: ``set`` alone) and scores the
worst metric of them. A trial is feasible when (a stated rule), in every scenario, its status
is ok (no divergence), no contact is lost (``contact_lost_s`` == 0) and no command reached the
clip (``command_at_limit_s`` == 0: max_effort or the joint's URDF effort; every
``tau_peak_*_Nm`` below ``max_effort``); an infeasible trial scores INFEASIBLE. The best feasible gains
and the thesis defaults are then run on the tuning and the held-out scenario; DIR gets
``best.yaml`` (a ROS params file of the best gains, for ``--params-file``), ``tune.json``
(the figures) and Ray Tune's own trial records (DIR/ray_tune).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import yaml

from cr_control.experiments import engine, evaluate
from cr_control.experiments.spec import (
    PLANT,
    Range,
    SpecError,
    Targets,
    check_keys,
    parse_spec,
    read_yaml,
    shown,
)
from cr_control.experiments.sweep import check_metrics

KEYS = ("scheme", "duration", "metric", "search", "samples", "seed", "set", "scenarios",
        "held_out")
INFEASIBLE = 1e6
NARROW = 3.0


def feasible(result: dict[str, Any], max_effort: float) -> tuple[bool, str]:
    """The module docstring's rule: (feasible, why not)."""
    if result.get("status") != "ok":
        return False, f"{result.get('status')}: {result.get('reason', '')}"
    if result.get("contact_lost_s", 0.0) > 0.0:
        return False, f"contact lost for {result['contact_lost_s']:.3f} s"
    if result.get("command_at_limit_s", 0.0) > 0.0:
        return False, f"a command at its clip for {result['command_at_limit_s']:.3f} s"
    peaks = {k: v for k, v in result.items() if k.startswith("tau_peak_")}
    over = [k for k, v in peaks.items() if not v < max_effort]
    if over:
        return False, f"{over[0]} at the clip ({max_effort:g})"
    return True, ""


def _max_effort(fixed: dict[str, Any], targets: Targets) -> float:
    """The controller's command clip (N m) in the tuning scenario."""
    controller, _ = targets.split(fixed)
    return float(controller.get("max_effort", targets.controller_base.get(
        "max_effort", targets.controller["max_effort"].default)))


def load(path: Path) -> tuple[dict[str, Any], Targets]:
    """The checked tune SPEC and its parameters (SpecError, one line)."""
    data = read_yaml(path)
    check_keys(data, KEYS, ("metric", "search", "held_out"), str(path))
    search = data["search"]
    if not isinstance(search, dict) or not search or \
            not all(isinstance(v, dict) for v in search.values()):
        raise SpecError("search must map live gains node.param to ranges {low, high, log}")
    sweep = {k: data[k] for k in ("scheme", "duration", "samples", "seed", "set") if k in data}
    spec, targets = parse_spec({**sweep, "vary": search}, str(path))
    for name in spec.vary:
        node = name.partition(".")[0]
        if node == PLANT or targets.param(name).read_only:
            raise SpecError(f"search: {name} is not a live gain of {spec.scheme}")
    scenarios = data.get("scenarios", [{}])
    if not isinstance(scenarios, list) or not scenarios or \
            not all(isinstance(x, dict) for x in scenarios):
        raise SpecError("scenarios must be a non-empty list of override mappings")
    for scenario in scenarios:
        targets.check({**spec.fixed, **scenario})
    held_out = data["held_out"]
    if not isinstance(held_out, dict) or not held_out:
        raise SpecError("held_out must map node.param to the validation scenario's values")
    targets.check({**spec.fixed, **held_out})
    if not isinstance(data["metric"], str):
        raise SpecError(f"metric must be a metric name, got {shown(data['metric'])}")
    spec.metrics = [data["metric"]]
    check_metrics(spec, targets, None)          # a short run: is the metric one a run has?
    return {"spec": spec, "metric": data["metric"], "held_out": dict(held_out),
            "scenarios": [dict(x) for x in scenarios]}, targets


def _space(ranges: dict[str, Range]) -> dict[str, Any]:
    # lazy: Ray takes seconds to import and only runs sweeps, tuning and the report
    from ray import tune

    return {name: (tune.loguniform(r.low, r.high) if r.log else tune.uniform(r.low, r.high))
            for name, r in ranges.items()}


def _narrowed(ranges: dict[str, Range], best: dict[str, float]) -> dict[str, Range]:
    out = {}
    for name, r in ranges.items():
        x = best[name]
        if r.log:
            out[name] = Range(max(r.low, x / NARROW), min(r.high, x * NARROW), True)
        else:
            half = (r.high - r.low) / 8
            out[name] = Range(max(r.low, x - half), min(r.high, x + half), False)
    return out


def search(cfg: dict[str, Any], targets: Targets, out: Path, cpus: int) -> list[dict[str, Any]]:
    """Both rounds on Ray Tune; every trial as {config, objective, result, feasible, why}."""
    # lazy: Ray takes seconds to import and only runs sweeps, tuning and the report
    from ray import tune
    from ray.tune.search.basic_variant import BasicVariantGenerator

    spec = cfg["spec"]
    metric = cfg["metric"]
    max_effort = _max_effort(spec.fixed, targets)
    scheme, robot, duration, fixed = spec.scheme, spec.robot, spec.duration, dict(spec.fixed)
    scenarios = cfg["scenarios"]

    def trial(config: dict[str, float]) -> dict[str, Any]:
        worst, ok, why = -math.inf, True, ""
        for scenario in scenarios:
            controller, plant = targets.split({**fixed, **scenario, **config})
            result = evaluate.run_point(scheme, robot, duration, controller, plant)
            good, reason = feasible(result, max_effort)
            value = result.get(metric, math.nan)
            if not math.isfinite(value):
                good, reason = False, reason or f"{metric} is {value}"
            ok, why = ok and good, why or reason
            worst = max(worst, float(value)) if math.isfinite(value) else math.inf
        objective = worst if ok and math.isfinite(worst) else INFEASIBLE
        return {"objective": objective, "feasible": ok, "why": why, metric: worst}

    trials: list[dict[str, Any]] = []
    ranges: dict[str, Range] = dict(spec.vary)              # type: ignore[arg-type]
    for round_, (count, seed) in enumerate(((spec.samples, spec.seed),
                                            (max(1, spec.samples // 2), spec.seed + 1))):
        tuner = tune.Tuner(
            tune.with_resources(trial, {"cpu": 1}), param_space=_space(ranges),
            tune_config=tune.TuneConfig(metric="objective", mode="min", num_samples=count,
                                        search_alg=BasicVariantGenerator(random_state=seed),
                                        max_concurrent_trials=cpus, reuse_actors=True),
            run_config=tune.RunConfig(storage_path=str((out / "ray_tune").absolute()),
                                      name=f"round{round_ + 1}", verbose=0))
        grid = tuner.fit()
        for r in grid:
            if r.metrics and "objective" in r.metrics:
                trials.append({"round": round_ + 1, "config": dict(r.config),
                               "objective": r.metrics["objective"],
                               "feasible": r.metrics.get("feasible", False),
                               "why": r.metrics.get("why", ""), metric: r.metrics.get(metric)})
        best = min(trials, key=lambda t: t["objective"])
        ranges = _narrowed(dict(spec.vary), best["config"])   # type: ignore[arg-type]
    return trials


def _evaluate(cfg: dict[str, Any], targets: Targets, gains: dict[str, Any], cpus: int
              ) -> dict[str, dict[str, Any]]:
    """Thesis and tuned gains on the tuning and held-out scenarios (4 Ray tasks)."""
    spec = cfg["spec"]
    cases = {"thesis/tuning": {}, "thesis/held_out": cfg["held_out"],
             "tuned/tuning": gains, "tuned/held_out": {**cfg["held_out"], **gains}}
    jobs = []
    for index, values in enumerate(cases.values()):
        controller, plant = targets.split({**spec.fixed, **values})
        jobs.append((index, {}, controller, plant))
    found: dict[int, dict[str, Any]] = {}
    engine.run(spec.scheme, spec.robot, spec.duration, jobs, cpus,
               lambda records: found.update((r["point"], r["result"]) for r in records), 1)
    return {name: found[i] for i, name in enumerate(cases)}


def params_file(scheme: str, gains: dict[str, Any], targets: Targets) -> str:
    """The best gains as a ROS params file (values spread as the nodes take them)."""
    controller, _ = targets.split(gains)
    values = {k: ([float(x) for x in v] if isinstance(v, list) else float(v))
              for k, v in controller.items()}
    text = yaml.safe_dump({scheme: {"ros__parameters": values}}, default_flow_style=None,
                          sort_keys=False)
    return f"# {scheme}: gains tuned by cr_tune (see tune.json next to this file)\n{text}"


def main(argv: Iterable[str] | None = None) -> int:
    """Entry point of ``cr_tune``; returns the exit status."""
    parser = argparse.ArgumentParser(prog="cr_tune", description="Tune a scheme's live gains "
                                     "on Ray Tune under constraints; validate on a held-out "
                                     "scenario; write the best gains as a ROS params file.")
    parser.add_argument("spec", type=Path, metavar="SPEC.yaml")
    parser.add_argument("--out", type=Path, required=True, metavar="DIR")
    parser.add_argument("--address", metavar="HOST:PORT", help="join this Ray cluster")
    parser.add_argument("--workers", type=int, metavar="N", help="local CPUs (default: all)")
    args = parser.parse_args(None if argv is None else list(argv))

    def error(message: str, status: int = 2) -> int:
        print(f"cr_tune: error: {message}", file=sys.stderr)
        return status

    try:
        cfg, targets = load(args.spec)
        args.out.mkdir(parents=True, exist_ok=True)
        cpus = engine.start(args.address, args.workers)
        trials = search(cfg, targets, args.out, cpus)
        feasible_trials = [t for t in trials if t["feasible"]]
        if not feasible_trials:
            return error(f"no feasible trial of {len(trials)}: e.g. {trials[0]['why']}", 1)
        best = min(feasible_trials, key=lambda t: t["objective"])
        checks = _evaluate(cfg, targets, best["config"], cpus)
    except SpecError as exc:
        return error(str(exc))
    except engine.EngineError as exc:
        return error(str(exc), 1)
    except OSError as exc:
        return error(f"--out {args.out}: {exc.strerror or exc}")
    finally:
        engine.stop()
    metric = cfg["metric"]
    spec = cfg["spec"]
    figures = {name: {"metric": r.get(metric), "status": r["status"],
                      "feasible": feasible(r, _max_effort(spec.fixed, targets))[0]}
               for name, r in checks.items()}
    thesis, tuned = figures["thesis/held_out"]["metric"], figures["tuned/held_out"]["metric"]
    ratio = thesis / tuned if thesis and tuned else math.nan
    (args.out / "best.yaml").write_text(params_file(spec.scheme, best["config"], targets))
    (args.out / "tune.json").write_text(json.dumps(
        {"spec": {**spec.canonical(), "metric": metric, "held_out": cfg["held_out"]},
         "best": best, "checks": figures, "held_out_ratio": ratio,
         "trials": len(trials), "feasible_trials": len(feasible_trials)}, indent=2,
        default=float) + "\n")
    for name, f in figures.items():
        print(f"{name:16s} {metric} = {f['metric']:.6g}  ({f['status']}, "
              f"{'feasible' if f['feasible'] else 'infeasible'})")
    print(f"held-out: thesis / tuned = {ratio:.2f}x  ({len(feasible_trials)} of {len(trials)} "
          f"trials feasible)")
    print(f"wrote {args.out / 'best.yaml'} and tune.json")
    return 0


if __name__ == "__main__":
    sys.exit(main())
