#!/usr/bin/env python3
"""Pareto plot of run time against error, from the CSV written by canopy_bench_accuracy.

    python3 bench/accuracy_plot.py out/bench/accuracy.csv out/bench/accuracy_pareto.png

One panel per ray set, one point per configuration: x = false misses per million rays (log scale),
y = Mrays/s. A configuration without false misses is drawn hollow at the 95 % upper bound of its
rate, 3/N per the rule of three (N rays), with an arrow to the left: its true rate is at most
that. The dashed line joins the Pareto-optimal points (faster, or fewer false misses).
Needs matplotlib (Debian: python3-matplotlib).
"""
import csv
import math
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

COLOURS = ["#1b6ca8", "#e07b00", "#2a9d3c", "#c0392b", "#7d3c98", "#555555"]
MARKERS = ["o", "s", "D", "^", "v", "P"]


def read_rows(path):
    with open(path, newline="", encoding="utf-8") as f:
        rows = list(csv.DictReader(f))
    if not rows:
        sys.exit(f"accuracy_plot: {path} holds no rows")
    for r in rows:
        r["rays"] = int(r["rays"])
        r["mrays_per_s"] = float(r["mrays_per_s"])
        r["false_miss_per_million"] = float(r["false_miss_per_million"])
    return rows


def pareto_front(points):
    """Points (x, y) not dominated by another with x' <= x and y' >= y, by increasing x."""
    front = []
    for x, y in sorted(points, key=lambda p: (p[0], -p[1])):
        if not front or y > front[-1][1]:
            front.append((x, y))
    return front


def main():
    if len(sys.argv) != 3:
        sys.exit("usage: accuracy_plot.py ACCURACY.csv OUT.png")
    rows = read_rows(sys.argv[1])
    configs = list(dict.fromkeys(r["config"] for r in rows))
    sets = list(dict.fromkeys(r["ray_set"] for r in rows))
    style = {c: (COLOURS[i % len(COLOURS)], MARKERS[i % len(MARKERS)]) for i, c in enumerate(configs)}

    # One x range for every panel, in whole decades, so that panels compare at a glance.
    xs = [3e6 / r["rays"] if r["false_miss_per_million"] == 0.0 else r["false_miss_per_million"] for r in rows]
    x_range = (10 ** math.floor(math.log10(min(xs) / 3)), 10 ** math.ceil(math.log10(max(max(xs), min(xs) * 100) * 2)))

    columns = min(3, len(sets))
    lines = math.ceil(len(sets) / columns)
    fig, axes = plt.subplots(lines, columns, figsize=(4.6 * columns, 3.9 * lines), squeeze=False)
    for k, name in enumerate(sets):
        ax = axes[k // columns][k % columns]
        points = []
        for r in (r for r in rows if r["ray_set"] == name):
            colour, marker = style[r["config"]]
            zero = r["false_miss_per_million"] == 0.0
            x = 3e6 / r["rays"] if zero else r["false_miss_per_million"]
            y = r["mrays_per_s"]
            points.append((x, y))
            ax.scatter([x], [y], s=60, marker=marker, zorder=3, edgecolors=colour, linewidths=1.8,
                       facecolors="white" if zero else colour)
            if zero:
                ax.annotate("", xy=(x / 2.2, y), xytext=(x / 1.15, y),
                            arrowprops=dict(arrowstyle="->", color=colour, lw=1.2))
        front = pareto_front(points)
        ax.plot([p[0] for p in front], [p[1] for p in front], ls="--", lw=1, color="#888888", zorder=2)
        ax.set_xscale("log")
        ax.set_xlim(*x_range)
        ax.set_ylim(0, max(p[1] for p in points) * 1.15)
        count = next(r["rays"] for r in rows if r["ray_set"] == name)
        ax.set_title(f"{name} ({count:,} rays)", fontsize=10)
        ax.set_xlabel("false misses per million rays")
        ax.set_ylabel("Mrays/s (1 thread)")
        ax.grid(True, which="major", ls=":", lw=0.6)
    for k in range(len(sets), lines * columns):
        axes[k // columns][k % columns].axis("off")

    handles = [plt.Line2D([], [], ls="", marker=style[c][1], color=style[c][0], markersize=8, label=c)
               for c in configs]
    handles.append(plt.Line2D([], [], ls="", marker="o", markerfacecolor="white", markeredgecolor="black",
                              markersize=8, label="no false miss: at the 95 % bound 3/N"))
    fig.legend(handles=handles, loc="lower center", ncol=min(3, len(handles)), frameon=False, fontsize=9)
    fig.suptitle("Run time against error: closest hit, exact reference (GMP)", fontsize=12)
    fig.tight_layout(rect=(0, 0.08 if lines > 1 else 0.14, 1, 0.96))
    fig.savefig(sys.argv[2], dpi=130)


if __name__ == "__main__":
    main()
