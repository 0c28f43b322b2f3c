#!/usr/bin/env python3
"""Summarises the output of canopy_bench_embree into the table of targets.

    build/release/bench/canopy_bench_embree --rounds 5 --threads-list 1,2 > embree.md
    bench/summarize_embree.py embree.md

Prints, for every scene, the ratio Canopy / Embree of the medians at 1 and 2 threads of each
figure that has a target (docs/performance.md), and whether the target is met. With --coherent
rows in the output, also the batch queries' table: the batch against Embree's best of packet8,
packet16 and stream (coherent sets), and against Canopy's single rays (random sets).
"""
import re
import sys

# (figure as the benchmark names it, label, target, True when larger is better)
TARGETS = [
    ("primary closest (Mrays/s)", "closest hit, primary rays", 1.2, True),
    ("random closest (Mrays/s)", "closest hit, random rays", 1.0, True),
    ("shadow any (Mrays/s)", "any hit, shadow rays", 1.0, True),
    ("primary closest + alpha (Mrays/s)", "alpha rule (filter), primary closest", 1.5, True),
    ("shadow any + alpha (Mrays/s)", "alpha rule (filter), shadow any", 1.5, True),
    ("primary closest + alpha (triangle hook) (Mrays/s)", "alpha rule (triangle hook), primary closest", None, True),
    # On request (--rays vertices,inside); rows of sets not traced are left out.
    ("vertices closest (Mrays/s)", "closest hit, rays through vertices", 1.0, True),
    ("vertices any (Mrays/s)", "any hit, rays through vertices", 1.0, True),
    ("inside closest (Mrays/s)", "closest hit, rays from inside thin solids", 1.0, True),
    ("inside any (Mrays/s)", "any hit, rays from inside thin solids", 1.0, True),
    ("memory (bytes/triangle stored)", "memory per triangle", 1.0, False),
    ("build (ms; ratio > 1: Canopy slower)", "build time", 1.0, False),
]


def table_rows(path):
    """(scene, cells) for each table row of the output under a scene's heading, and (scene, None)
    at the heading itself."""
    scene = None
    for line in open(path, encoding="utf-8"):
        heading = re.match(r"## (\S+)", line)
        if heading:
            scene = heading.group(1)
            yield scene, None
            continue
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if scene is not None and len(cells) >= 5:
            yield scene, cells


def cell_text(got, goal, larger=True):
    """The figures of one cell (1 and 2 threads), in bold when a goal is missed; – when none."""
    got = [g for g in got if g is not None]
    if not got:
        return "–"
    text = " / ".join(f"{g:.2f}" for g in got)
    if goal is None or all((g >= goal) if larger else (g <= goal) for g in got):
        return text
    return f"**{text}**"


def parse(path):
    """{scene: {(threads, figure): ratio of medians}}"""
    scenes = {}
    for scene, cells in table_rows(path):
        values = scenes.setdefault(scene, {})
        if cells is not None and cells[4].startswith("**"):
            values[(cells[0], cells[1])] = float(cells[4].strip("*"))
    return scenes


# (ray set and query, label, target, what the ratio compares) of the --coherent rows.
COHERENT_TARGETS = [
    ("primary closest", "primary closest", 1.2, "embree"),
    ("primary any", "primary any", 1.0, "embree"),
    ("shadow any", "shadow any", 1.0, "embree"),
    ("random closest", "random closest, batch / single", 0.97, "single"),
    ("random any", "random any, batch / single", 0.97, "single"),
]


def parse_coherent(path):
    """{scene: {(threads, figure): (batch / Embree's best, batch / single)}} of the --coherent rows."""
    scenes = {}
    for scene, cells in table_rows(path):
        if cells is None or ", batch vs Embree " not in cells[1]:
            continue
        single = re.search(r"batch / single ([0-9.]+)", cells[1])
        figure = cells[1].split(", batch vs Embree ")[0]
        scenes.setdefault(scene, {})[(cells[0], figure)] = (
            float(cells[4].strip("*")), float(single.group(1)) if single else None)
    return scenes


def print_coherent(scenes):
    print()
    print("| scene | " + " | ".join(f"{label} (≥ {goal})" for _, label, goal, _ in COHERENT_TARGETS) + " |")
    print("|---|" + "---|" * len(COHERENT_TARGETS))
    for name, values in scenes.items():
        cells = []
        for figure, _, goal, against in COHERENT_TARGETS:
            pairs = [values.get((t, figure)) for t in ("1", "2")]
            cells.append(cell_text([p[0] if against == "embree" else p[1] for p in pairs if p is not None], goal))
        print(f"| {name} | " + " | ".join(cells) + " |")


def main():
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    scenes = parse(sys.argv[1])
    names = list(scenes)
    print("| target | goal | " + " | ".join(names) + " |")
    print("|---|---|" + "---|" * len(names))
    for figure, label, goal, larger in TARGETS:
        cells = []
        for name in names:
            values = scenes[name]
            if figure.startswith("memory"):
                got = [values.get(("–", figure))]
            else:
                got = [values.get((t, figure)) for t in ("1", "2")]
            cells.append(cell_text(got, goal, larger))
        if all(c == "–" for c in cells):
            continue
        goal_text = "–" if goal is None else (f"≥ {goal}" if larger else f"≤ {goal}")
        print(f"| {label} | {goal_text} | " + " | ".join(cells) + " |")
    coherent = parse_coherent(sys.argv[1])
    if coherent:
        print_coherent(coherent)


if __name__ == "__main__":
    main()
