"""Runs as flat rows, runs.csv, and the per-variant summary computed from rows alone.

A row is one (scenario, variant) flight: plain named values (no arrays), so the summary that
``companion bench`` prints and writes can be recomputed from runs.csv by anyone, and the tests
check exactly that. Per-vehicle values are columns named ``<vehicle>_<metric>``.
"""

from __future__ import annotations

import csv
import math
import statistics
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from enum import Enum
from typing import TYPE_CHECKING, Any

from companion.bench.weights import COLUMNS as WEIGHT_COLUMNS
from companion.planning.metrics import UNSAFE_REASONS, FailureReason

if TYPE_CHECKING:
    from companion.planning.coordination.certificate import OcclusionCertificate

# PlannerCounts summed over the vehicles from the summary (no_rollout_ticks comes from the ticks,
# companion.bench.diagnose, so that a baseline without rollouts reports 0 as well)
PLANNER_SUMS = ("escape_ticks", "stall_detours", "timed_replans")
DEFAULT_VARIANTS = ("astar-bdwa", "astar-bdwa-nosparse", "bdwa", "dwa")  # the paper's Table IV ablation

RUN_COLUMNS: tuple[tuple[str, type], ...] = (
    ("seed", int), ("index", int), ("scenario", str), ("variant", str),
    ("success", bool), ("success_strict", bool), ("reason", str), ("failure_t_s", float),
    ("duration_s", float), ("min_separation_m", float), ("los_blocked_fraction", float),
    ("crossing_occluded", bool), ("planner_ms_per_tick", float), ("wall_s", float), ("error", str),
    # How often the planners left plain tracking, summed over the vehicles (PlannerCounts):
    ("no_rollout_ticks", int), ("escape_ticks", int), ("stall_detours", int), ("timed_replans", int),
    # The coordination the run flew under (ScheduleRecord): the mission's settings and the plan's hold.
    ("hold_s_max", float), ("forecast", str), ("departure_hold_s", float),
    ("failed_vehicles", str), ("hit_obstacle", str), ("hit_moving", bool), ("hit_from_behind", bool),
    # The occlusion certificate under the mission's rule, of the forecast the run's variant flies:
    # feasible / needs-hold / infeasible, and the least departure hold of the first vehicle.
    ("cert_whole_flight", str), ("cert_whole_flight_hold_s", float),
    ("cert_closest_approach", str), ("cert_closest_approach_hold_s", float),
    # The scored sight-line pairs (the mission's sightline.pairs, or the paper's pair): how many,
    # and at how many closest approaches the line was blocked; each pair's own in PAIR_COLUMNS.
    ("sight_pairs", int), ("sight_pairs_occluded", int),
)
# Per scored pair, named <higher>-<lower>_<metric> (e.g. a-b_crossing_occluded), after the vehicles.
PAIR_COLUMNS: tuple[tuple[str, type], ...] = (("los_blocked_fraction", float), ("crossing_occluded", bool))
# Per assigned pair (missions with sightline.pairs), its own certificate, as the cert_* columns are the first's.
PAIR_CERT_COLUMNS: tuple[tuple[str, type], ...] = (
    ("cert_whole_flight", str), ("cert_whole_flight_hold_s", float),
    ("cert_closest_approach", str), ("cert_closest_approach_hold_s", float))
VEHICLE_COLUMNS: tuple[tuple[str, type], ...] = (
    ("arrived", bool), ("flight_time_s", float), ("path_length_m", float), ("lower_bound_s", float),
    ("ratio", float), ("min_obstacle_clearance_m", float), ("nodes_raw", int), ("nodes_sparse", int),
)


def run_row(seed: int, index: int, scenario: str, variant: str, summary: Mapping[str, Any] | None, *,
            wall_s: float, reason: FailureReason | None = None, error: str | None = None,
            facts: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """One CSV row from a run's ``summary_dict()`` (+ diagnose facts); without a summary
    (no_path, error) only the identity, the reason and the error message are filled."""
    row: dict[str, Any] = {"seed": seed, "index": index, "scenario": scenario, "variant": variant,
                           "wall_s": round(wall_s, 3), "error": error, **(facts or {})}
    if summary is None:
        row.update(success=False, success_strict=False, reason=FailureReason(reason or FailureReason.ERROR))
        return row
    for key, _ in RUN_COLUMNS:
        if key in summary:
            row[key] = summary[key]
    for key in PLANNER_SUMS:
        if isinstance(summary.get(f"planner_{key}"), Mapping):
            row[key] = int(sum(summary[f"planner_{key}"].values()))
    row.update(summary.get("schedule") or {})
    for name, metrics in summary.get("vehicles", {}).items():
        for key, _ in VEHICLE_COLUMNS:
            row[f"{name}_{key}"] = metrics.get(key)
    sight = [p for p in summary.get("sight_pairs", ()) if p in summary.get("pairs", {})]
    row["sight_pairs"] = len(sight)
    row["sight_pairs_occluded"] = sum(1 for p in sight if summary["pairs"][p]["crossing_occluded"])
    for pair in sight:
        for key, _ in PAIR_COLUMNS:
            row[f"{pair}_{key}"] = summary["pairs"][pair][key]
    return row


class CertVerdict(str, Enum):
    """A certificate question's answer under the mission's rule (how runs.csv spells it)."""

    FEASIBLE = "feasible"
    NEEDS_HOLD = "needs-hold"  # feasible only after a departure hold the rule does not allow
    INFEASIBLE = "infeasible"  # no hold within the time limit helps


def certificate_columns(cert: "OcclusionCertificate | None",
                        pairs: "Sequence[OcclusionCertificate]" = ()) -> dict[str, Any]:
    """The ``cert_*`` columns of a scenario's headline certificate (empty without one: a single
    vehicle), and ``<pair>_cert_*`` for each of ``pairs`` (a mission's assigned pairs)."""
    if cert is None:
        return {}

    def verdict(ok: bool, hold: float | None) -> str:
        return (CertVerdict.FEASIBLE if ok else CertVerdict.INFEASIBLE if hold is None
                else CertVerdict.NEEDS_HOLD).value

    def of(c: "OcclusionCertificate", prefix: str) -> dict[str, Any]:
        return {f"{prefix}cert_whole_flight": verdict(c.whole_flight, c.whole_flight_min_hold_s),
                f"{prefix}cert_whole_flight_hold_s": c.whole_flight_min_hold_s,
                f"{prefix}cert_closest_approach": verdict(c.closest_approach, c.closest_approach_min_hold_s),
                f"{prefix}cert_closest_approach_hold_s": c.closest_approach_min_hold_s}

    return {**of(cert, ""), **{k: v for c in pairs for k, v in of(c, f"{c.pair}_").items()}}


def _column_prefixes(rows: Iterable[Mapping[str, Any]], suffix: str) -> list[str]:
    """What precedes ``suffix`` in the rows' column names, in order of first appearance."""
    names: list[str] = []
    for row in rows:
        for key in row:
            if key.endswith(suffix) and key[:-len(suffix)] not in names:
                names.append(key[:-len(suffix)])
    return names


def vehicle_names(rows: Iterable[Mapping[str, Any]]) -> list[str]:
    """Vehicle names in order of first appearance (from ``<name>_arrived`` columns)."""
    return _column_prefixes(rows, "_arrived")


def pair_names(rows: Iterable[Mapping[str, Any]]) -> list[str]:
    """Scored sight-line pairs in order of first appearance (from ``<pair>_crossing_occluded``,
    then ``<pair>_cert_closest_approach``)."""
    rows = list(rows)
    return list(dict.fromkeys(_column_prefixes(rows, "_crossing_occluded")
                              + _column_prefixes(rows, "_cert_closest_approach")))


def columns(rows: Sequence[Mapping[str, Any]]) -> list[str]:
    """runs.csv's header: the run columns, the score weights when a sweep set them, per vehicle,
    per scored sight-line pair."""
    weights = [k for k in WEIGHT_COLUMNS if any(k in r for r in rows)]
    return ([k for k, _ in RUN_COLUMNS] + weights
            + [f"{n}_{k}" for n in vehicle_names(rows) for k, _ in VEHICLE_COLUMNS]
            + [f"{p}_{k}" for p in pair_names(rows) for k, _ in PAIR_COLUMNS]
            + [f"{p}_{k}" for p in pair_names(rows) for k, _ in PAIR_CERT_COLUMNS if any(f"{p}_{k}" in r for r in rows)])


def _cell(value: Any) -> str:
    if value is None:
        return ""
    if isinstance(value, float):
        return repr(value) if math.isfinite(value) else ""
    return str(value)


def write_runs_csv(rows: Sequence[Mapping[str, Any]], path: str | Path) -> Path:
    path = Path(path)
    header = columns(rows)
    with path.open("w", newline="", encoding="utf-8") as fh:
        writer = csv.writer(fh)
        writer.writerow(header)
        for row in rows:
            writer.writerow([_cell(row.get(k)) for k in header])
    return path


def _typed(kind: type, text: str) -> Any:
    if text == "":
        return None
    if kind is bool:
        if text not in ("True", "False"):
            raise ValueError(f"not a boolean: {text!r}")
        return text == "True"
    return kind(text)


def read_runs_csv(path: str | Path) -> list[dict[str, Any]]:
    """runs.csv back as typed rows (empty cells are None)."""
    kinds = {**dict(RUN_COLUMNS), **{k: float for k in WEIGHT_COLUMNS}}
    suffix_kinds = {**dict(VEHICLE_COLUMNS), **dict(PAIR_COLUMNS), **dict(PAIR_CERT_COLUMNS)}
    with Path(path).open(newline="", encoding="utf-8") as fh:
        reader = csv.DictReader(fh)
        rows = []
        for raw in reader:
            row: dict[str, Any] = {}
            for key, text in raw.items():
                kind = kinds.get(key)
                if kind is None:
                    kind = next((k for s, k in suffix_kinds.items() if key.endswith("_" + s)), str)
                row[key] = _typed(kind, text)
            rows.append(row)
    return rows


def _stats(values: Sequence[float]) -> dict[str, Any]:
    if not values:
        return {"n": 0, "mean": None, "median": None, "min": None, "max": None}
    return {"n": len(values), "mean": round(statistics.fmean(values), 3),
            "median": round(statistics.median(values), 3),
            "min": round(min(values), 3), "max": round(max(values), 3)}


def aggregate(rows: Iterable[Mapping[str, Any]]) -> dict[str, dict[str, Any]]:
    """Per-variant summary of rows, in order of first appearance of each variant.

    Flight times and ratios to the lower bound are over successful runs only (the paper's
    "among the accomplished tasks"). ``common`` repeats them over the scenarios that every
    variant in ``rows`` completed, the only like-for-like comparison of times.
    """
    rows = list(rows)
    names = vehicle_names(rows)
    variants = list(dict.fromkeys(r["variant"] for r in rows))
    ok_by_variant = {v: {(r["seed"], r["index"]) for r in rows if r["variant"] == v and r["success"]}
                     for v in variants}
    common = set.intersection(*ok_by_variant.values()) if variants else set()
    out: dict[str, dict[str, Any]] = {}
    for variant in variants:
        mine = [r for r in rows if r["variant"] == variant]
        ok = [r for r in mine if r["success"]]
        ok_common = [r for r in ok if (r["seed"], r["index"]) in common]
        reasons: dict[str, int] = {}
        for r in mine:
            if not r["success"]:
                reasons[r["reason"] or "unknown"] = reasons.get(r["reason"] or "unknown", 0) + 1
        ms = [r["planner_ms_per_tick"] for r in mine if r.get("planner_ms_per_tick") is not None]
        out[variant] = {
            "runs": len(mine),
            "successes": len(ok),
            "success_rate": round(len(ok) / len(mine), 4) if mine else None,
            "strict_successes": sum(1 for r in mine if r["success_strict"]),
            "strict_rate": round(sum(1 for r in mine if r["success_strict"]) / len(mine), 4) if mine else None,
            "collisions": sum(1 for r in mine if r["reason"] == FailureReason.COLLISION),
            "unsafe": sum(1 for r in mine if r["reason"] in UNSAFE_REASONS),
            "collisions_moving": sum(1 for r in mine if r["reason"] == FailureReason.COLLISION and r.get("hit_moving")),
            "runs_with_holds": sum(1 for r in mine if (r.get("no_rollout_ticks") or 0) > 0),
            "runs_with_escapes": sum(1 for r in mine if (r.get("escape_ticks") or 0) > 0),
            "reasons": dict(sorted(reasons.items(), key=lambda kv: (-kv[1], kv[0]))),
            "flight_time_s": {n: _stats([r[f"{n}_flight_time_s"] for r in ok]) for n in names},
            "ratio_to_bound": {n: _stats([r[f"{n}_ratio"] for r in ok if r.get(f"{n}_ratio") is not None])
                               for n in names},
            "common_scenarios": len(common),
            "flight_time_common_s": {n: _stats([r[f"{n}_flight_time_s"] for r in ok_common]) for n in names},
            "los_blocked_fraction": _stats([r["los_blocked_fraction"] for r in ok
                                            if r.get("los_blocked_fraction") is not None]),
            "min_separation_m": _stats([r["min_separation_m"] for r in ok if r.get("min_separation_m") is not None]),
            "sight_pairs": {"scored": sum(r.get("sight_pairs") or 0 for r in mine),
                            "occluded": sum(r.get("sight_pairs_occluded") or 0 for r in mine)},
            "planner_ms_per_tick": round(statistics.fmean(ms), 4) if ms else None,
            "wall_s": round(sum(r["wall_s"] for r in mine), 3),
            **_certificate_summary(mine, names),
        }
    return out


def _certificate_summary(mine: Sequence[Mapping[str, Any]], names: Sequence[str]) -> dict[str, Any]:
    """Certificate counts of a variant's scenarios (the headline, and over every assigned pair's
    own); strict successes among those whose closest approach it calls feasible (for every
    assigned pair); ratios to the bound over successes needing no hold."""
    counts = {q: {v.value: sum(1 for r in mine if r.get(f"cert_{q}") == v.value) for v in CertVerdict}
              for q in ("whole_flight", "closest_approach")}
    pairs = [f"{p}_cert_closest_approach" for p in pair_names(mine)]
    per_pair = {v.value: sum(1 for r in mine for key in pairs if r.get(key) == v.value) for v in CertVerdict}
    feasible = [r for r in mine if r.get("cert_closest_approach") == CertVerdict.FEASIBLE.value
                and all(r.get(key) in (None, CertVerdict.FEASIBLE.value) for key in pairs)]
    strict = sum(1 for r in feasible if r["success_strict"])
    return {"certificate": counts, "pair_certificates": per_pair,
            "strict_where_feasible": {"scenarios": len(feasible), "strict": strict,
                                      "rate": round(strict / len(feasible), 4) if feasible else None},
            "ratio_to_bound_no_hold": {n: _stats([r[f"{n}_ratio"] for r in feasible if r["success"]
                                                  and r.get(f"{n}_ratio") is not None]) for n in names}}


def certificate_text(s: Mapping[str, Any]) -> str:
    """A variant's certificate counts as one short phrase (feasible / needs hold / infeasible)."""
    def part(q: str) -> str:
        c = s["certificate"][q]
        return f"{c['feasible']} / {c['needs-hold']} / {c['infeasible']}"
    return f"closest approach {part('closest_approach')}, whole flight {part('whole_flight')}"


def _strict_feasible_text(s: Mapping[str, Any]) -> str:
    w = s["strict_where_feasible"]
    return "-" if not w["scenarios"] else f"{w['strict']}/{w['scenarios']} ({100 * w['rate']:.1f} %)"


def format_table(summary: Mapping[str, Mapping[str, Any]]) -> str:
    """The results table printed by ``companion bench`` (plain text, one line per variant)."""
    names = list(next(iter(summary.values()))["flight_time_s"]) if summary else []

    def num(x: Any, fmt: str) -> str:
        return "-" if x is None else format(x, fmt)

    head = f"{'variant':<22}{'success':>15}{'strict':>15}{'coll.':>6}"
    for n in names:
        head += f"{'t_' + n + ' mean/med (s)':>22}{'t/bound':>9}"
    lines = [head, "-" * len(head)]
    for variant, s in summary.items():
        line = (f"{variant:<22}{s['successes']:>5}/{s['runs']:<3} {num(100 * s['success_rate'], '5.1f')}%"
                f"{s['strict_successes']:>5}/{s['runs']:<3} {num(100 * s['strict_rate'], '5.1f')}%"
                f"{s['collisions']:>6}")
        for n in names:
            ft, ratio = s["flight_time_s"][n], s["ratio_to_bound"][n]
            line += f"{num(ft['mean'], '.1f') + ' / ' + num(ft['median'], '.1f'):>22}{num(ratio['mean'], '.3f'):>9}"
        lines.append(line)
    lines.append("")
    for variant, s in summary.items():
        reasons = ", ".join(f"{k} {v}" for k, v in s["reasons"].items()) or "none"
        lines.append(f"failures {variant}: {reasons}")
    for variant, s in summary.items():
        pairs = s.get("sight_pairs") or {}
        if pairs.get("scored"):
            lines.append(f"sight pairs {variant}: blocked at closest approach in {pairs['occluded']} of "
                         f"{pairs['scored']} scored pairs")
    if summary and any(sum(c.values()) for c in next(iter(summary.values()))["certificate"].values()):
        lines.append("")
        for variant, s in summary.items():
            ratios = ", ".join(f"{n} {num(st['mean'], '.3f')}" for n, st in s["ratio_to_bound_no_hold"].items())
            lines.append(f"certificate {variant} (feasible / needs hold / infeasible): {certificate_text(s)}; "
                         f"strict where feasible {_strict_feasible_text(s)}; x bound where feasible: {ratios}")
            pairs = s.get("pair_certificates") or {}
            if sum(pairs.values()):
                lines.append(f"certificate per assigned pair {variant}: closest approach {pairs['feasible']} / "
                             f"{pairs['needs-hold']} / {pairs['infeasible']}")
    return "\n".join(lines)


# The paper's Table IV (successes / runs) and the mean flight times it quotes (section VI.C).
PAPER_TABLE_IV: dict[str, dict[str, Any]] = {
    "astar-bdwa": {"successes": 106, "runs": 120, "t_a_s": 570.0, "t_b_s": 662.0},
    "astar-bdwa-nosparse": {"successes": 78, "runs": 120, "t_a_s": None, "t_b_s": None},
    "bdwa": {"successes": 52, "runs": 120, "t_a_s": 871.0, "t_b_s": 938.0},
}


def markdown_table(summary: Mapping[str, Mapping[str, Any]]) -> str:
    """Our Table IV beside the paper's, as Markdown (written to table.md by the bench)."""
    names = list(next(iter(summary.values()))["flight_time_s"])[:2] if summary else []

    def ft(s: Mapping[str, Any], n: str) -> str:
        st = s["flight_time_s"][n]
        ratio = s["ratio_to_bound"][n]["mean"]
        if st["mean"] is None:
            return "-"
        return f"{st['mean']:.0f} / {st['median']:.0f} ({ratio:.2f})" if ratio is not None else f"{st['mean']:.0f}"

    head = ["variant", "paper success", "our success", "strict", "collisions", "failures"]
    head += [f"{n}: mean / median s (x bound)" for n in names] + ["paper mean a / b s"]
    head += ["certificate: feasible / needs hold / infeasible", "strict where feasible",
             "x bound where feasible (" + " / ".join(names) + ")"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for variant, s in summary.items():
        paper = PAPER_TABLE_IV.get(variant)
        p_ok = "-" if paper is None else f"{paper['successes']}/{paper['runs']} ({100 * paper['successes'] / paper['runs']:.1f} %)"
        p_t = "-" if paper is None or paper["t_a_s"] is None else f"{paper['t_a_s']:.0f} / {paper['t_b_s']:.0f}"
        fails = ", ".join(f"{k} {v}" for k, v in s["reasons"].items()) or "none"
        cells = [f"`{variant}`", p_ok, f"**{s['successes']}/{s['runs']} ({100 * s['success_rate']:.1f} %)**",
                 f"{s['strict_successes']}/{s['runs']} ({100 * s['strict_rate']:.1f} %)", str(s["collisions"]), fails]
        cells += [ft(s, n) for n in names] + [p_t]
        no_hold = s["ratio_to_bound_no_hold"]
        cells += [certificate_text(s), _strict_feasible_text(s),
                  " / ".join("-" if no_hold[n]["mean"] is None else f"{no_hold[n]['mean']:.3f}" for n in names)]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)
