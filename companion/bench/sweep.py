"""Does the choice of score weights change flight times? Pure analysis of a weight sweep's rows.

The paper (section VI) claims that "changing weights of score has little effect on UAV flying
time". A sweep flies the same seeded scenarios with every weight set of a grid; this module
summarises each set (success, flight-time distribution, time over the lower bound) and compares
it with the paper's weights scenario by scenario:

    paired ratio = t_UAV(scenario, weights) / t_UAV(scenario, paper's weights)

for every UAV of every scenario that both weight sets completed. The claim is judged by
:data:`LITTLE` (fixed before any sweep was run): a weight set has "little effect" when its median
paired ratio is within 5 % of 1 and its median flight time per UAV within 5 % of the paper's
weights' median. The verdict counts the sets that break either, and reports success separately
(weights may change whether a flight completes even where they do not change its duration).
"""

from __future__ import annotations

import statistics
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from companion.bench.table import vehicle_names
from companion.bench.weights import Weights

LITTLE = 0.05  # a relative change of at most 5 % is "little"


def _stats(values: Sequence[float]) -> dict[str, Any]:
    if not values:
        return {"n": 0, "median": None, "mean": None, "p10": None, "p90": None}
    v = np.asarray(values, dtype=float)
    return {"n": len(values), "median": round(float(np.median(v)), 4), "mean": round(float(v.mean()), 4),
            "p10": round(float(np.percentile(v, 10)), 4), "p90": round(float(np.percentile(v, 90)), 4)}


def by_weights(rows: Sequence[Mapping[str, Any]]) -> dict[Weights, list[Mapping[str, Any]]]:
    out: dict[Weights, list[Mapping[str, Any]]] = {}
    for r in rows:
        w = Weights.from_row(r)
        if w is None:
            raise ValueError("a row without weight columns is not a sweep row")
        out.setdefault(w, []).append(r)
    return out


def _flight_times(rows: Sequence[Mapping[str, Any]], name: str) -> dict[int, float]:
    """Scenario index -> this UAV's flight time, for the successful runs."""
    return {r["index"]: r[f"{name}_flight_time_s"] for r in rows if r["success"]}


def paired_ratios(rows: Sequence[Mapping[str, Any]], reference_rows: Sequence[Mapping[str, Any]],
                  names: Sequence[str]) -> list[float]:
    """t / t_reference per UAV, over the scenarios both sets of rows completed (scenario order)."""
    out = []
    for n in names:
        mine, ref = _flight_times(rows, n), _flight_times(reference_rows, n)
        out += [mine[i] / ref[i] for i in sorted(mine.keys() & ref.keys())]
    return out


def summarise(rows: Sequence[Mapping[str, Any]], reference: Weights) -> list[dict[str, Any]]:
    """One entry per weight set (in order of appearance): success, flight times and ratios to the
    bound per UAV, and the paired ratios to ``reference`` (which must be among the rows)."""
    groups = by_weights(rows)
    if reference not in groups:
        raise ValueError(f"the reference weights {reference.label} were not flown")
    names = vehicle_names(rows)
    ref_times = {n: _flight_times(groups[reference], n) for n in names}
    ref_median = {n: statistics.median(ref_times[n].values()) if ref_times[n] else None for n in names}
    out = []
    for w, mine in groups.items():
        ok = [r for r in mine if r["success"]]
        entry: dict[str, Any] = {"weights": w.columns(), "label": w.label, "reference": w == reference,
                                 "runs": len(mine), "successes": len(ok),
                                 "success_rate": round(len(ok) / len(mine), 4),
                                 "reasons": _reasons(mine), "flight_time_s": {}, "ratio_to_bound": {},
                                 "median_vs_reference": {}}
        for n in names:
            times = _flight_times(mine, n)
            entry["flight_time_s"][n] = _stats(list(times.values()))
            entry["ratio_to_bound"][n] = _stats([r[f"{n}_ratio"] for r in ok if r.get(f"{n}_ratio") is not None])
            median = entry["flight_time_s"][n]["median"]
            entry["median_vs_reference"][n] = (None if median is None or not ref_median[n]
                                               else round(median / ref_median[n] - 1.0, 4))
        paired = paired_ratios(mine, groups[reference], names)
        entry["paired_ratio"] = _stats(paired)
        entry["paired_changed_over_little"] = (round(sum(abs(p - 1.0) > LITTLE for p in paired) / len(paired), 4)
                                               if paired else None)
        entry["little_effect"] = _little(entry)
        out.append(entry)
    return out


def _reasons(rows: Sequence[Mapping[str, Any]]) -> dict[str, int]:
    reasons: dict[str, int] = {}
    for r in rows:
        if not r["success"]:
            reasons[r["reason"] or "unknown"] = reasons.get(r["reason"] or "unknown", 0) + 1
    return dict(sorted(reasons.items(), key=lambda kv: (-kv[1], kv[0])))


def _little(entry: Mapping[str, Any]) -> bool | None:
    median = entry["paired_ratio"]["median"]
    if median is None:
        return None
    return abs(median - 1.0) <= LITTLE and all(c is not None and abs(c) <= LITTLE
                                               for c in entry["median_vs_reference"].values())


def verdict(summary: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """The claim judged over the grid: which sets break "little effect", and how far times move."""
    others = [e for e in summary if not e["reference"]]
    broken = [e["label"] for e in others if e["little_effect"] is False]
    medians = [e["paired_ratio"]["median"] for e in others if e["paired_ratio"]["median"] is not None]
    changed = [e["paired_changed_over_little"] for e in others if e["paired_changed_over_little"] is not None]
    spread = {}
    for n in summary[0]["median_vs_reference"] if summary else ():
        moves = [e["median_vs_reference"][n] for e in summary if e["median_vs_reference"][n] is not None]
        spread[n] = [min(moves), max(moves)] if moves else None
    rates = [e["success_rate"] for e in summary]
    return {
        "threshold": LITTLE,
        "weight_sets": len(summary),
        "sets_breaking_little_effect": broken,
        "paired_median_ratio_range": [min(medians), max(medians)] if medians else None,
        "median_time_change_range": spread,
        "share_of_flights_changed_over_little": [min(changed), max(changed)] if changed else None,
        "success_rate_range": [min(rates), max(rates)] if rates else None,
        "claim_holds": not broken if medians else None,
    }


def markdown_table(summary: Sequence[Mapping[str, Any]]) -> str:
    """One line per weight set; the paper's weights in bold."""
    names = list(summary[0]["flight_time_s"]) if summary else []

    def pct(x: float | None) -> str:
        return "-" if x is None else f"{100 * x:+.1f} %"

    def times(s: Mapping[str, Any]) -> str:
        return "-" if s["median"] is None else f"{s['median']:.0f} / {s['mean']:.0f} / {s['p90']:.0f}"

    head = (["w_h / w_d / w_s", "success"] + [f"UAV {n}: median / mean / p90 s" for n in names]
            + ["t / bound, mean " + " / ".join(names), "paired t / t(paper's), median [p10, p90]",
               "flights changed > 5 %", "little effect"])
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for e in summary:
        label = f"**{e['label']}** (paper)" if e["reference"] else e["label"]
        ratio = " / ".join("-" if e["ratio_to_bound"][n]["mean"] is None else f"{e['ratio_to_bound'][n]['mean']:.3f}"
                           for n in names)
        p = e["paired_ratio"]
        paired = "-" if p["median"] is None else f"{p['median']:.3f} [{p['p10']:.3f}, {p['p90']:.3f}]"
        changed = "-" if e["paired_changed_over_little"] is None else f"{100 * e['paired_changed_over_little']:.0f} %"
        little = {True: "yes", False: "**no**", None: "-"}[e["little_effect"]]
        cells = ([label, f"{e['successes']}/{e['runs']}"] + [times(e["flight_time_s"][n]) for n in names]
                 + [ratio, paired, changed, "reference" if e["reference"] else little])
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def verdict_text(v: Mapping[str, Any]) -> str:
    """The judgement in a few plain sentences."""
    if v["claim_holds"] is None:
        return "No weight set completed a scenario that the paper's weights also completed: nothing to judge."
    lo, hi = v["paired_median_ratio_range"]
    moves = "; ".join(f"UAV {n} {100 * r[0]:+.1f} to {100 * r[1]:+.1f} %"
                      for n, r in v["median_time_change_range"].items() if r)
    c_lo, c_hi = v["share_of_flights_changed_over_little"]
    s_lo, s_hi = v["success_rate_range"]
    head = ("The claim holds" if v["claim_holds"] else
            f"The claim does not hold for {len(v['sets_breaking_little_effect'])} of {v['weight_sets'] - 1} weight sets "
            f"({', '.join(v['sets_breaking_little_effect'])})")
    return (f"{head} at a {100 * v['threshold']:.0f} % threshold. Per-scenario paired median ratios to the "
            f"paper's weights span {lo:.3f}-{hi:.3f}; median flight times move {moves}; "
            f"{100 * c_lo:.0f}-{100 * c_hi:.0f} % of individual flights change by more than "
            f"{100 * v['threshold']:.0f} %; success rates span {100 * s_lo:.1f}-{100 * s_hi:.1f} %.")
