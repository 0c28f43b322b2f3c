#!/usr/bin/env python3
"""Writes assets/tree.png: the RGBA billboard texture of the JSON example scene (128x128).

A tree silhouette (trunk and a crown of overlapping leaf discs) on a fully transparent
background whose colour is kept dark purple, so that a renderer that ignores alpha shows
the whole quad. Deterministic; standard library only.
"""
import math
import random
import struct
import sys
import zlib

SIZE = 128


def tree_pixels():
    rng = random.Random(20)
    blobs = [(64 + rng.uniform(-30, 30), 48 + rng.uniform(-30, 24), rng.uniform(8, 16)) for _ in range(26)]
    rows = []
    for y in range(SIZE):
        row = []
        for x in range(SIZE):
            r, g, b, a = 60, 20, 70, 0  # background: transparent
            if 58 <= x <= 70 and y >= 70:  # trunk
                shade = 0.8 + 0.2 * math.sin(x * 0.9)
                r, g, b, a = int(110 * shade), int(72 * shade), int(40 * shade), 255
            for cx, cy, rad in blobs:  # crown
                d = math.hypot(x - cx, y - cy)
                if d <= rad:
                    light = 0.65 + 0.35 * (1 - d / rad) - 0.2 * (y / SIZE)
                    r, g, b, a = int(40 * light), int(150 * light), int(50 * light), 255
            row.append((r, g, b, a))
        rows.append(row)
    return rows


def write_png(path, rows):
    raw = b"".join(b"\x00" + bytes(c for px in row for c in px) for row in rows)

    def chunk(tag, data):
        return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)

    png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", SIZE, SIZE, 8, 6, 0, 0, 0))
    png += chunk(b"IDAT", zlib.compress(raw, 9)) + chunk(b"IEND", b"")
    with open(path, "wb") as f:
        f.write(png)


if __name__ == "__main__":
    write_png(sys.argv[1] if len(sys.argv) > 1 else "assets/tree.png", tree_pixels())
