#!/usr/bin/env python3
"""canopy render --mode batch against --mode single: the whole command's render time, image by
image, medians of interleaved rounds, 1 and 2 threads; and a check that both modes wrote the same
image files byte for byte.

    python3 bench/render_modes.py [--canopy build/release/tools/canopy] [--rounds 5] [--threads 1,2]
                                  [--size 800x600] [--quick]

Cases: the demo (figures 1-3 in the mode; the heat map is always traced pixel by pixel and is
left out), and glmark2's bunny and the 2CylinderEngine CAD model (Debian's glmark2-data and
assimp-testmodels) with the primary, AO and path kernels. Prints one Markdown table: median
render time per mode and the speed-up (single time / batch time; > 1: the batch is faster)."""
import argparse
import filecmp
import os
import re
import statistics
import subprocess
import sys
import tempfile

BUNNY = "/usr/share/glmark2/models/bunny.obj"
ENGINE = "/usr/share/assimp/models/glTF2/2CylinderEngine-glTF-Binary/2CylinderEngine.glb"


def cases(quick):
    out = [("demo (figures 1-3)", [], ["1_billboards_alpha_ignored.png", "2_texture_alpha_mask.png",
                                       "3_procedural_alpha_mask.png"])]
    for name, path in (("bunny", BUNNY), ("engine", ENGINE)):
        if not os.path.exists(path):
            print(f"# {path} is missing: the {name} cases are left out", file=sys.stderr)
            continue
        stem = os.path.splitext(os.path.basename(path))[0] + ".png"
        for kernel, spp in (("primary", 1), ("ao", 2 if quick else 4), ("path", 2 if quick else 4)):
            out.append((f"{name} {kernel} ({spp} spp)", [path, "--kernel", kernel, "--spp", str(spp)], [stem]))
    return out


def run(canopy, args, mode, threads, size, folder, images):
    cmd = [canopy, "render", *args, "-o", folder, "--size", size, "--mode", mode, "--threads", str(threads)]
    text = subprocess.run(cmd, check=True, capture_output=True, text=True).stdout
    seconds = 0.0
    for image in images:
        m = re.search(re.escape(image) + r": ([0-9.]+) ms", text)
        if not m:
            sys.exit(f"no time for {image} in the output of {' '.join(cmd)}:\n{text}")
        seconds += float(m.group(1)) * 1e-3
    return seconds


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--canopy", default="build/release/tools/canopy")
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--threads", default="1,2")
    parser.add_argument("--size", default="800x600")
    parser.add_argument("--quick", action="store_true", help="fewer samples for ao and path")
    options = parser.parse_args()
    print("| case | threads | single (ms) | batch (ms) | speed-up |")
    print("| --- | --- | --- | --- | --- |")
    with tempfile.TemporaryDirectory() as tmp:
        for name, args, images in cases(options.quick):
            for threads in [int(t) for t in options.threads.split(",")]:
                times = {"single": [], "batch": []}
                for r in range(options.rounds):
                    order = ("single", "batch") if r % 2 == 0 else ("batch", "single")
                    for mode in order:
                        times[mode].append(run(options.canopy, args, mode, threads, options.size,
                                               os.path.join(tmp, mode), images))
                for image in images:
                    if not filecmp.cmp(os.path.join(tmp, "single", image), os.path.join(tmp, "batch", image),
                                       shallow=False):
                        sys.exit(f"{name}: {image} differs between the modes")
                single = statistics.median(times["single"])
                batch = statistics.median(times["batch"])
                print(f"| {name} | {threads} | {single * 1e3:.1f} | {batch * 1e3:.1f} | {single / batch:.2f} |",
                      flush=True)


if __name__ == "__main__":
    main()
