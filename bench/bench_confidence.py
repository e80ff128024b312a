"""Is an event's confidence right as often as it says? The posterior over fault hypotheses
that the event page heads (``app.services.events.confidence``) scored against the simulator's
truth on the built-in nonlinear engine.

The demo's active design ("all health parameters", subset m = 10, the product's path: 11
sensors, fuel flow an input) is built as the demo builds it; its confusion is the product's
nonlinear-engine evaluation job (``engine_evaluation.run_engine_evaluation``, the job's default
settings: 25 engines per seed 002 fault, seed 0), as the event page reads it. Then new faulted
fleets of other seeds are isolated the same way (``evaluate_engine.evaluate_design``: the
sensor-space WSSR of the 20 records after the fault, each fit held to the library's
magnitudes), and every event's posterior is computed as the event page computes it
(``posterior.fault_posterior``: the WSSR likelihood at the fit's own degrees of freedom, times
the confusion column of the isolated fault, tempered as the evaluation job fitted it on a
second fleet of its own, ``posterior.fit_tempering``).

Printed: the reliability table (events binned by the confidence of the fault they name: how
often that fault is the true one against the mean confidence in the bin), the expected
calibration error, how often the 90 % credible set (the page's label, "HPT or Wf") holds the
true fault, the Brier score; over every event and over those the product names on evidence
(the fault explains ``shift_detector.EVIDENCE_THRESHOLD`` of the change; the others are shown
unisolated in service). Peers in the same run: the product before the tempering (the
isolation's margin, the confusion at full weight), the WSSR posterior alone (no confusion) and
the confusion alone (Bayes on the isolated fault's column).

    .venv/bin/python bench/bench_confidence.py [--engines 40] [--seeds 1,2,3]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import _common
import numpy as np

from app.engine_cache import engine_schedule
from app.services.demo import fleet as demo_fleet
from app.services.designs import engine_evaluation
from app.services.designs import service as designs
from estimation import evaluate_engine as ee
from estimation import isolation, posterior
from estimation.shift_detector import EVIDENCE_THRESHOLD, SENSOR_WSSR_MARGIN

TARGET = ("target: over the events named on evidence (the product's), each bin's hit rate within "
          "10 points of its mean confidence (bins of 50+ events) and the 90 % credible set "
          "holding the truth >= 90 %; over every event, calibration error <= 0.05")


def demo_engine_design(sched: object) -> ee.EngineDesign:
    """The demo's active design as the design service makes it, in the engine run's form."""
    method, m = demo_fleet.ACTIVE_DESIGN
    p = demo_fleet.DESIGN_POINT
    model = sched.model_at(p["alt"], p["mach"], p["power"])  # type: ignore[attr-defined]
    sensors = [n for n in model.sensor_names if n != "Wf"]
    result = designs.design_step(model, demo_fleet.design_spec(method, m, sensors))
    design, note = engine_evaluation.engine_design(result, source="builtin",
                                                   name=f"{method}:{m}")
    assert design is not None, note
    return design


def scored(label: str, post: posterior.FaultPosterior, truth: np.ndarray) -> list[str]:
    named = post.posterior.argmax(axis=-1)
    confidence = post.posterior.max(axis=-1)
    hit = named == truth
    rel = posterior.reliability(confidence, hit)
    sets = post.credible_set(0.9)
    in_set = np.mean([post.faults[t] in s for s, t in zip(sets, truth, strict=True)])
    onehot = np.eye(len(post.faults))[truth]
    brier = float(np.mean(np.sum((post.posterior - onehot) ** 2, axis=-1)))
    lines = [f"  {label}: {len(truth)} events, named right {hit.mean():.1%}, mean confidence "
             f"{confidence.mean():.1%}; calibration error {rel.calibration_error:.3f}; 90 % "
             f"credible set holds the truth {in_set:.1%} (mean size "
             f"{np.mean([len(s) for s in sets]):.2f}); Brier {brier:.3f}"]
    lines += [f"    confidence {lo:4.2f}-{hi:4.2f}: {n:5d} events, mean {c:6.1%}, right {r:6.1%}"
              for lo, hi, n, c, r in rel.rows()]
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--engines", type=int, default=40, help="engines per fault per seed")
    ap.add_argument("--seeds", default="1,2,3")
    ap.add_argument("--cache", type=Path, default=Path("/tmp/fh/cache"))
    args = ap.parse_args()
    print(_common.load_line())
    print(TARGET)
    sched = engine_schedule(args.cache)
    design = demo_engine_design(sched)
    t0 = time.perf_counter()
    settings = engine_evaluation.EngineRunSettings()
    job = engine_evaluation.run_engine_evaluation(design, sched, tuple(), settings)
    confusion = np.asarray(job["confusion_percent"], float)
    faults = tuple(job["faults"])
    tempering = posterior.Tempering.from_dict(job["posterior"])
    print(f"design {design.name}: the evaluation job's confusion ({settings.engines_per_fault} "
          f"engines per fault, seed {settings.seed}) {job['percent_correct']:.1f} % correct, "
          f"{time.perf_counter() - t0:.0f} s; tempering fitted on {tempering.events} other "
          f"events: WSSR scale {tempering.scale:.2f}, confusion weight "
          f"{tempering.confusion_power:.2f} (mean log score {tempering.log_score:.3f}, "
          f"untempered {tempering.default_score:.3f})")
    wssr, dof, truth, explained = [], [], [], []
    for seed in (int(s) for s in args.seeds.split(",")):
        rec = ee.simulate_records(args.engines, rng=np.random.default_rng(1000 + seed),
                                  faults=isolation.SEED_002_FAULTS,
                                  n_before=settings.records_before,
                                  n_after=settings.records_after)
        r = ee.evaluate_design(design, rec, sched)
        wssr.append(r.wssr)
        dof.append(r.dof)
        truth.append(r.true_fault)
        explained.append(r.explained)
    W, D, T, X = (np.concatenate(a) for a in (wssr, dof, truth, explained))
    print(f"scored on {len(T)} new events (seeds {args.seeds}, {args.engines} engines per fault "
          f"each), {time.perf_counter() - t0:.0f} s")
    for subset, keep in (("every event", np.ones(len(T), bool)),
                         ("events named on evidence", X >= EVIDENCE_THRESHOLD)):
        print(f"\n{subset}:")
        product = posterior.fault_posterior(
            W[keep], D[keep], faults, confusion=confusion, scale=tempering.scale,
            confusion_power=tempering.confusion_power)
        before = posterior.fault_posterior(W[keep], D[keep], faults, confusion=confusion,
                                           scale=SENSOR_WSSR_MARGIN)
        alone = posterior.fault_posterior(W[keep], D[keep], faults, scale=SENSOR_WSSR_MARGIN)
        column = posterior.confusion_posterior(confusion, floor=0.5)[:, product.isolated].T
        counted = posterior.FaultPosterior(faults, column, column, product.isolated,
                                           product.fit_probability)
        for label, post in (("the product (tempered WSSR x confusion)", product),
                            ("before: WSSR x confusion untempered", before),
                            ("peer: WSSR alone (the isolation's margin)", alone),
                            ("peer: confusion alone", counted)):
            print("\n".join(scored(label, post, T[keep])))
    print(_common.load_line())


if __name__ == "__main__":
    main()
