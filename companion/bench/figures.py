"""The ablation's figures from runs.csv rows: Fig. 13(a) lines and Fig. 13(b) violins.

matplotlib's object API on the Agg canvas (as companion.plots): no pyplot, no global state.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from companion.bench.table import vehicle_names

VARIANT_COLORS = {"astar-bdwa": "tab:red", "astar-bdwa-nosparse": "tab:orange",
                  "bdwa": "tab:blue", "dwa": "tab:gray"}


def _color(variant: str, k: int) -> str:
    return VARIANT_COLORS.get(variant, f"C{k}")


def _upper_limit(values: Sequence[float]) -> float | None:
    """A y limit that keeps the bulk readable: the max, unless a few far outliers (beyond 1.6x
    the 95th percentile) would squash everything; those are then marked at the top instead."""
    if not values:
        return None
    p95 = float(np.percentile(values, 95))
    top = float(max(values))
    return top * 1.03 if top <= 1.6 * p95 else 1.3 * p95


def _mark_clipped(ax, xs: Sequence[float], ys: Sequence[float], limit: float | None, color: str) -> None:
    """Label the values above ``limit`` at the top edge, one label per x."""
    above: dict[float, list[float]] = {}
    for x, y in zip(xs, ys):
        if limit is not None and y > limit:
            above.setdefault(x, []).append(y)
    for x, ys_above in above.items():
        text = f"{max(ys_above):.0f} s" if len(ys_above) == 1 else f"{len(ys_above)} up to {max(ys_above):.0f} s"
        ax.annotate(text, (x, limit), xytext=(0, -12), textcoords="offset points", ha="center",
                    fontsize=6, color=color, arrowprops={"arrowstyle": "->", "color": color, "lw": 0.6})


def _variants(rows: Sequence[Mapping[str, Any]]) -> list[str]:
    return list(dict.fromkeys(r["variant"] for r in rows))


def violin_figure(rows: Sequence[Mapping[str, Any]], *, title: str | None = None) -> Figure:
    """Flight-time distributions of successful runs, one violin per variant and UAV, with a
    box plot inside and the success count under each (Fig. 13b)."""
    variants = _variants(rows)
    names = vehicle_names(rows)
    fig = Figure(figsize=(max(6.0, 1.6 * len(variants) * len(names)), 5.0), dpi=110)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    positions, labels = [], []
    everything = [r[f"{n}_flight_time_s"] for r in rows if r["success"] for n in names]
    limit = _upper_limit(everything)
    pos = 0.0
    for k, variant in enumerate(variants):
        for j, name in enumerate(names):
            times = [r[f"{name}_flight_time_s"] for r in rows if r["variant"] == variant and r["success"]]
            _mark_clipped(ax, [pos] * len(times), times, limit, _color(variant, k))
            labels.append(f"{variant}\nUAV {name} (n={len(times)})")
            positions.append(pos)
            if len(times) >= 2:
                parts = ax.violinplot([times], positions=[pos], widths=0.8, showextrema=False)
                for body in parts["bodies"]:
                    body.set_facecolor(_color(variant, k))
                    body.set_alpha(0.35 if j else 0.6)
            if times:
                ax.boxplot([times], positions=[pos], widths=0.18, showfliers=True, patch_artist=True,
                           boxprops={"facecolor": "white"}, medianprops={"color": "k"},
                           flierprops={"markersize": 3})
            pos += 1.0
        pos += 0.5
    ax.set_xticks(positions, labels, fontsize=7)
    if limit is not None:
        ax.set_ylim(top=limit)
    ax.set_ylabel("flight time of successful runs (s)")
    ax.set_title(title or "Flight-time distributions per variant and UAV (cf. paper Fig. 13b)")
    ax.grid(True, axis="y", lw=0.3, alpha=0.6)
    fig.tight_layout()
    return fig


def lines_figure(rows: Sequence[Mapping[str, Any]], *, title: str | None = None) -> Figure:
    """Flight time per scenario index for each variant, one panel per UAV; failed runs are
    gaps in the line and crosses on the bottom axis (Fig. 13a)."""
    variants = _variants(rows)
    names = vehicle_names(rows)
    fig = Figure(figsize=(11.0, 3.2 * max(len(names), 1)), dpi=110)
    FigureCanvasAgg(fig)
    if not names:  # no run got as far as flying (every one errored): say so instead of crashing
        ax = fig.add_subplot(1, 1, 1)
        ax.text(0.5, 0.5, "no run produced flight times", ha="center", va="center", transform=ax.transAxes)
        return fig
    axes = [fig.add_subplot(len(names), 1, j + 1) for j in range(len(names))]
    indices = sorted({r["index"] for r in rows})
    pos = {i: k for k, i in enumerate(indices)}
    for ax, name in zip(axes, names):
        limit = _upper_limit([r[f"{name}_flight_time_s"] for r in rows if r["success"]])
        for k, variant in enumerate(variants):
            y = np.full(len(indices), np.nan)
            failed = []
            for r in rows:
                if r["variant"] != variant:
                    continue
                if r["success"]:
                    y[pos[r["index"]]] = r[f"{name}_flight_time_s"]
                else:
                    failed.append(r["index"])
            ok = int(np.count_nonzero(~np.isnan(y)))
            _mark_clipped(ax, indices, list(y), limit, _color(variant, k))
            ax.plot(indices, y, lw=1.0, marker=".", ms=3, color=_color(variant, k),
                    label=f"{variant} ({ok}/{len(indices)} ok, {len(failed)} failed)")
            if failed:  # stacked per variant just above the bottom axis
                ax.plot(failed, [0.03 + 0.04 * k] * len(failed), ls="none", marker="x", ms=5, color=_color(variant, k),
                        transform=ax.get_xaxis_transform(), clip_on=False)
        if limit is not None:
            ax.set_ylim(top=limit)
        ax.set_ylabel(f"UAV {name} flight time (s)")
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax.grid(True, lw=0.3, alpha=0.6)
        ax.legend(fontsize=7, loc="upper right", ncol=2)
    axes[-1].set_xlabel("scenario index (x at the bottom: failed run)")
    axes[0].set_title(title or "Flight time per scenario (cf. paper Fig. 13a)")
    fig.tight_layout()
    return fig


def weight_sweep_figure(rows: Sequence[Mapping[str, Any]], summary: Sequence[Mapping[str, Any]], *,
                        title: str | None = None) -> Figure:
    """One box per weight set: above, each UAV's flight time over its time with the paper's
    weights on the same scenario (the band is +-5 %); below, flight time over the lower bound,
    with the success count on top. The paper's weights are red."""
    from companion.bench.sweep import LITTLE, by_weights, paired_ratios
    from companion.bench.weights import Weights

    groups = by_weights(rows)
    names = vehicle_names(rows)
    sets = [Weights.from_row(e["weights"]) for e in summary]
    reference = sets[[e["reference"] for e in summary].index(True)]
    fig = Figure(figsize=(max(8.0, 0.38 * len(sets) + 2.0), 7.5), dpi=110)
    FigureCanvasAgg(fig)
    top, bottom = fig.add_subplot(2, 1, 1), fig.add_subplot(2, 1, 2)
    xs = np.arange(len(sets))
    paired = [paired_ratios(groups[w], groups[reference], names) for w in sets]
    bounds = [[r[f"{n}_ratio"] for r in groups[w] if r["success"] for n in names if r.get(f"{n}_ratio") is not None]
              for w in sets]
    for ax, data in ((top, paired), (bottom, bounds)):
        kept = [k for k, d in enumerate(data) if d]
        if kept:
            boxes = ax.boxplot([data[k] for k in kept], positions=xs[kept], widths=0.6, patch_artist=True,
                               medianprops={"color": "k"}, flierprops={"markersize": 2.5})
            for k, box in zip(kept, boxes["boxes"]):
                box.set_facecolor("tab:red" if sets[k] == reference else "tab:blue")
                box.set_alpha(0.6)
        ax.grid(True, axis="y", lw=0.3, alpha=0.6)
    top.axhspan(1.0 - LITTLE, 1.0 + LITTLE, color="tab:green", alpha=0.12, lw=0, label=f"within {100 * LITTLE:.0f} %")
    top.axhline(1.0, color="k", lw=0.6)
    top.set_ylabel("t / t with the paper's weights\n(same UAV, same scenario)")
    top.legend(fontsize=7, loc="upper right")
    top.set_xticks(xs, [""] * len(sets))
    bottom.set_ylabel("flight time / lower bound")
    for k, e in enumerate(summary):
        bottom.annotate(f"{e['successes']}/{e['runs']}", (xs[k], 1.0), xycoords=("data", "axes fraction"),
                        xytext=(0, 2), textcoords="offset points", ha="center", fontsize=6, rotation=90)
    bottom.set_xticks(xs, [w.label for w in sets], rotation=90, fontsize=7)
    bottom.set_xlabel("w_h / w_d / w_s (red: the paper's 0.37 / 0.6 / 0.8); success count on top")
    top.set_title(title or "Score weights vs flight time (successful runs, both UAVs pooled)")
    fig.tight_layout()
    return fig


def save(fig: Figure, path: str | Path) -> Path:
    path = Path(path)
    fig.savefig(path)
    return path
