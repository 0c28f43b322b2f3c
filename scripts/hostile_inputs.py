#!/usr/bin/env python3
# Hostile-input battery for the `canopy` command line (nothing crashes, hangs, blows up
# or lies). Entry point: scripts/hostile_inputs.sh [--quick] [--canopy PATH] [--jobs N]
# [--limit-kib N] [--timeout S] [--keep] [FILTER...].
#
# It generates, in a temporary folder, a battery of hostile inputs (deep recursion, huge fan-outs,
# devices / FIFOs / folders in every role, images claiming huge sizes, images over a total texel
# budget, one mesh file referred to 10^5 times and through nested scene files, counts of 2*10^9,
# NaN/Inf in every numeric field, truncated files of each format, damaged GLB headers and chunks,
# random bytes, UTF-16, 10 MB tokens, degenerate cameras and transforms, schema violations,
# malformed command-line numbers, unwritable outputs) and runs each through `canopy info`, `render` (8x8) or `trace` under `ulimit -v` (the
# address-space limit, default 4 GiB) and `timeout` (default 30 s). Each case states its expected
# outcome: an error (exit 1 or 2, the message names the file or option and matches a pattern) or
# a success (exit 0, the output matches a pattern). A run is classified as
#   crash   killed by a signal, exit >= 128, or a sanitizer report;
#   hang    over the time limit;
#   limit   out of memory (std::bad_alloc, "out of memory", killed under the ulimit);
#   silent  exit 0 where an error is due, an error that does not name the file or the problem,
#           a wrong exit status, or an output line longer than 300 characters;
#   ok      the expected outcome.
# One line per case, then a summary; exit status 1 when any case is not ok. FILTER words select
# the cases whose name contains one of them; --quick runs the first case of each group (the
# name up to its second '-') and skips the slow ones (under 60 s on 2 cores).
import argparse
import base64
import concurrent.futures
import json
import os
import random
import re
import shutil
import struct
import subprocess
import sys
import tempfile
import time
import zlib

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MAX_LINE = 300


class Case:
    def __init__(self, name, args, expect, pattern, names=None, slow=False, codes=None):
        self.name = name
        self.args = args          # argument list after `canopy`
        self.expect = expect      # "error" or "ok"
        self.pattern = pattern    # regex searched (case-insensitive) in stderr (error) or stdout (ok)
        self.names = names        # substring the error must contain (the file or option); None: none
        self.slow = slow
        self.codes = codes or ((1,) if expect == "error" else (0,))


CASES = []


def add(name, args, expect, pattern, names=None, slow=False, codes=None):
    CASES.append(Case(name, args, expect, pattern, names, slow, codes))


def write(path, data):
    mode = "wb" if isinstance(data, (bytes, bytearray)) else "w"
    with open(path, mode) as f:
        f.write(data)
    return path


# ---- valid bases -----------------------------------------------------------------------------

TRI_OBJ = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"
PLY_ASCII = ("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
             "element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n")
OFF_ASCII = "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"
STL_ASCII = ("solid t\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nvertex 0 1 0\nendloop\n"
             "endfacet\nendsolid t\n")


def ply_binary(nv=3, nf=1):
    head = ("ply\nformat binary_little_endian 1.0\nelement vertex %d\nproperty float x\nproperty float y\n"
            "property float z\nelement face %d\nproperty list uchar int vertex_indices\nend_header\n" % (nv, nf))
    body = struct.pack("<9f", 0, 0, 0, 1, 0, 0, 0, 1, 0) + struct.pack("<B3i", 3, 0, 1, 2)
    return head.encode() + body


def stl_binary(count=1, tris=1):
    data = b"\0" * 80 + struct.pack("<I", count)
    for _ in range(tris):
        data += struct.pack("<12fH", 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1, 0, 0)
    return data


def gltf_doc(positions=(0, 0, 0, 1, 0, 0, 0, 1, 0)):
    buf = struct.pack("<%df" % len(positions), *positions)
    return {
        "asset": {"version": "2.0"},
        "buffers": [{"byteLength": len(buf), "uri": "data:application/octet-stream;base64," +
                     base64.b64encode(buf).decode()}],
        "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": len(buf)}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": len(positions) // 3, "type": "VEC3",
                       "min": [0, 0, 0], "max": [1, 1, 0]}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
        "nodes": [{"mesh": 0}],
        "scenes": [{"nodes": [0]}],
        "scene": 0,
    }


def glb_bytes(doc, binary=b""):
    js = json.dumps(doc).encode()
    js += b" " * (-len(js) % 4)
    chunks = struct.pack("<II", len(js), 0x4E4F534A) + js
    if binary:
        binary += b"\0" * (-len(binary) % 4)
        chunks += struct.pack("<II", len(binary), 0x004E4942) + binary
    return struct.pack("<III", 0x46546C67, 2, 12 + len(chunks)) + chunks


def json_scene(nodes, meshes=None, prototypes=None, materials=None):
    doc = {"version": 1, "meshes": meshes if meshes is not None else
           [{"name": "t", "positions": [0, 0, 0, 1, 0, 0, 0, 1, 0], "indices": [0, 1, 2]}],
           "nodes": nodes}
    if prototypes is not None:
        doc["prototypes"] = prototypes
    if materials is not None:
        doc["materials"] = materials
    return json.dumps(doc)


def png_chunk(kind, data):
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xffffffff)


def png_bytes(w, h, idat_raw_bytes, color_type=6):
    ihdr = struct.pack(">IIBBBBB", w, h, 8, color_type, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + png_chunk(b"IHDR", ihdr) +
            png_chunk(b"IDAT", zlib.compress(idat_raw_bytes, 1)) + png_chunk(b"IEND", b""))


def small_png():
    raw = b"".join(b"\0" + b"\xff\x80\x40\xff" * 2 for _ in range(2))
    return png_bytes(2, 2, raw)


# ---- the battery -----------------------------------------------------------------------------

def build(d, canopy):
    j = lambda *p: os.path.join(d, *p)
    rng = random.Random(15)
    out = j("out")
    os.makedirs(out, exist_ok=True)
    R = ["render", "--size", "8x8", "-o", out]   # render prefix
    write(j("tri.obj"), TRI_OBJ)
    write(j("one.rays"), struct.pack("<8f", 0.2, 0.2, 1, 0, 0, 0, -1, 10))
    write(j("ok.png"), small_png())

    # special files in every role -------------------------------------------------------------
    os.mkfifo(j("fifo"))
    os.makedirs(j("folder.d"))
    specials = {"zero": "/dev/zero", "fifo": j("fifo"), "folder": j("folder.d"), "null": "/dev/null"}
    kind_re = {"zero": "character device", "null": "character device", "fifo": "FIFO", "folder": "folder"}
    for k, target in specials.items():
        for ext in ["obj", "json", "gltf", "glb", "ply", "off", "stl", "inst", "om"]:
            link = j("%s_as_scene.%s" % (k, ext))
            os.symlink(target, link)
            add("special-scene-%s-%s" % (k, ext), ["info", link], "error", kind_re[k], os.path.basename(link))
        link = j("%s_as_scene_render.obj" % k)
        os.symlink(target, link)
        add("special-scene-render-%s" % k, R + [link], "error", kind_re[k], os.path.basename(link))
        # as a mesh of a JSON scene, of an .inst, as an OBJ's mtllib, texture of OBJ and JSON
        write(j("%s_mesh.json" % k), json_scene([{"type": "mesh", "mesh": "m"}],
                                                 meshes=[{"name": "m", "file": target}]))
        add("special-mesh-json-%s" % k, ["info", j("%s_mesh.json" % k)], "error", kind_re[k], os.path.basename(target))
        write(j("%s_mesh.inst" % k), "mesh %s\n1 0 0 0 0 1 0 0 0 0 1 0\n" % target)
        add("special-mesh-inst-%s" % k, ["info", j("%s_mesh.inst" % k)], "error", kind_re[k], os.path.basename(target))
        add("special-mesh-inst-trace-%s" % k, ["trace", "--scene", j("%s_mesh.inst" % k), "--rays", j("one.rays"),
                                                "--query", "closest", "--out", j("out", "h.hits")],
            "error", kind_re[k], os.path.basename(target))
        write(j("%s_mtl.obj" % k), "mtllib %s\n" % target + TRI_OBJ)
        add("special-mtllib-%s" % k, ["info", j("%s_mtl.obj" % k)], "error", kind_re[k], os.path.basename(target))
        write(j("%s_tex.mtl" % k), "newmtl m\nmap_Kd %s\n" % target)
        write(j("%s_tex.obj" % k), "mtllib %s_tex.mtl\nusemtl m\n" % k + TRI_OBJ)
        add("special-texture-obj-%s" % k, R + [j("%s_tex.obj" % k)], "error", kind_re[k], os.path.basename(target))
        write(j("%s_tex.json" % k), json_scene([{"type": "mesh", "mesh": "t"}], materials=[{"name": "m", "texture": target}],
                                                meshes=[{"name": "t", "material": "m", "positions": [0, 0, 0, 1, 0, 0, 0, 1, 0],
                                                         "uvs": [0, 0, 1, 0, 0, 1], "indices": [0, 1, 2]}]))
        add("special-texture-json-%s" % k, ["info", j("%s_tex.json" % k)], "error", kind_re[k], os.path.basename(target))
        add("special-rays-%s" % k, ["trace", "--scene", j("tri.obj"), "--rays", target, "--query", "any",
                                     "--out", j("out", "h.hits")], "error", kind_re[k], os.path.basename(target))
        add("special-plugin-%s" % k, ["info", "--plugins", "--plugin", target], "error", kind_re[k],
            os.path.basename(target))
        # glTF buffer uri
        doc = gltf_doc()
        os.symlink(target, j("%s_buf.bin" % k))   # glTF URIs are relative to the file
        doc["buffers"][0]["uri"] = "%s_buf.bin" % k
        write(j("%s_buf.gltf" % k), json.dumps(doc))
        add("special-gltf-buffer-%s" % k, ["info", j("%s_buf.gltf" % k)], "error", kind_re[k], "%s_buf.bin" % k)

    # plugins that are not plugins
    write(j("random.so"), bytes(rng.getrandbits(8) for _ in range(4096)))
    write(j("text.so"), "not a plugin\n")
    write(j("empty.so"), b"")
    for p in ["random.so", "text.so", "empty.so", "missing.so"]:
        add("plugin-bad-%s" % p, ["info", "--plugins", "--plugin", j(p)], "error", "plugin|shared|not found|load", p)

    # images claiming huge sizes -----------------------------------------------------------------
    for w, h, mb in [(16384, 16384, 1), (65535, 65535, 0.01), (1, 2**31 - 1, 0.01), (2**31 - 1, 1, 0.01),
                     (9000, 9000, 0.1)]:
        raw = bytes(rng.getrandbits(8) for _ in range(int(mb * 2**20)))
        name = "huge_%dx%d.png" % (w, h)
        write(j(name), png_bytes(w, h, raw))
        write(j(name + ".mtl"), "newmtl m\nmap_Kd %s\n" % name)
        write(j(name + ".obj"), "mtllib %s.mtl\nusemtl m\nvt 0 0\nvt 1 0\nvt 0 1\n" % name +
              "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1/1 2/2 3/3\n")
        add("png-huge-obj-%dx%d" % (w, h), ["info", j(name + ".obj")], "error", "texels|limit|image", name)
        write(j(name + ".json"), json_scene([{"type": "mesh", "mesh": "t"}], materials=[{"name": "m", "texture": name}],
                                            meshes=[{"name": "t", "material": "m", "positions": [0, 0, 0, 1, 0, 0, 0, 1, 0],
                                                     "uvs": [0, 0, 1, 0, 0, 1], "indices": [0, 1, 2]}]))
        add("png-huge-json-%dx%d" % (w, h), R + [j(name + ".json")], "error", "texels|limit|image", name)
    # small images over a small --max-total-texels: the texels of a scene's images together (ok.png is 2x2;
    # each file once, however many materials name it), checked from each header before decoding
    for k in range(3):
        write(j("tex%d.png" % k), small_png())
    tri_uv = {"name": "t", "material": "m0", "positions": [0, 0, 0, 1, 0, 0, 0, 1, 0], "uvs": [0, 0, 1, 0, 0, 1],
              "indices": [0, 1, 2]}
    write(j("textures3.json"), json_scene([{"type": "mesh", "mesh": "t"}], meshes=[tri_uv], materials=[
        {"name": "m%d" % k, "texture": "tex%d.png" % (k % 3)} for k in range(6)]))
    add("png-total-json-ok", ["info", j("textures3.json"), "--max-total-texels", "12"], "ok", r"3 images")
    add("png-total-json-over", ["info", j("textures3.json"), "--max-total-texels", "11"], "error",
        r"materials\[2\]\.texture: .*tex2\.png: image is 2 × 2 \(4 texels\): with the 8 texels of the images loaded "
        r"before it, 12 texels in all exceed the limit of 11 \(--max-total-texels\)", "textures3.json")
    write(j("textures2.mtl"), "newmtl a\nmap_Kd tex0.png\nmap_d tex1.png\nnewmtl b\nmap_Kd tex2.png\n")
    write(j("textures2.obj"), "mtllib textures2.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl a\nf 1 2 3\nusemtl b\nf 1 2 3\n")
    # material a's colour image is held while its alpha image (merged into it) is read
    add("png-total-obj-over", ["info", j("textures2.obj"), "--max-total-texels", "7"], "error",
        r"textures2\.mtl:3: texture 'tex1\.png': .*with the 4 texels .* 8 texels in all exceed the limit of 7 "
        r"\(--max-total-texels\)", "tex1.png")
    add("png-total-obj-ok", ["info", j("textures2.obj"), "--max-total-texels", "8"], "ok", r"2 images")
    doc = gltf_doc()
    uv = struct.pack("<6f", 0, 0, 1, 0, 0, 1)
    doc["buffers"].append({"byteLength": 24, "uri": "data:application/octet-stream;base64," + base64.b64encode(uv).decode()})
    doc["bufferViews"].append({"buffer": 1, "byteLength": 24})
    doc["accessors"].append({"bufferView": 1, "componentType": 5126, "count": 3, "type": "VEC2"})
    prim = doc["meshes"][0]["primitives"][0]
    prim["attributes"]["TEXCOORD_0"] = 1
    doc["meshes"][0]["primitives"] = [dict(prim, material=k) for k in range(3)]
    doc["images"] = [{"uri": "data:image/png;base64," + base64.b64encode(small_png()).decode()},
                     {"uri": "data:image/png;base64," + base64.b64encode(small_png()[:-12] + png_chunk(b"tEXt", b"a\0b") +
                                                                         small_png()[-12:]).decode()},
                     {"uri": "tex0.png"}]
    doc["textures"] = [{"source": k} for k in range(3)]
    doc["materials"] = [{"pbrMetallicRoughness": {"baseColorTexture": {"index": k}}} for k in range(3)]
    write(j("textures3.gltf"), json.dumps(doc))
    add("png-total-gltf-ok", ["info", j("textures3.gltf"), "--max-total-texels", "12"], "ok", r"3 images")
    add("png-total-gltf-embedded", ["info", j("textures3.gltf"), "--max-total-texels", "7"], "error",
        r"images\[1\]: embedded image is 2 × 2 \(4 texels\): with the 4 texels .* 8 texels in all exceed the limit of 7 "
        r"\(--max-total-texels\)", "textures3.gltf")
    add("png-total-gltf-file", ["info", j("textures3.gltf"), "--max-total-texels", "11"], "error",
        r"images\[2\]: 'tex0\.png': .*with the 8 texels .* 12 texels in all exceed the limit of 11", "textures3.gltf")
    add("png-total-render", R + [j("textures3.json"), "--max-total-texels", "4"], "error", "--max-total-texels",
        "textures3.json")
    for bad in ["0", "-1", "1e9", "12x"]:
        add("png-total-option-%s" % bad, ["info", j("textures3.json"), "--max-total-texels", bad], "error",
            "--max-total-texels", None, codes=(2,))
    # a small image over a small --max-texels, a truncated PNG, random bytes as a PNG
    add("png-over-max-texels", ["info", j("huge_9000x9000.png.obj"), "--max-texels", "100"], "error", "max-texels",
        "huge_9000x9000.png")
    for name, data in [("trunc.png", small_png()[:40]), ("random.png", bytes(rng.getrandbits(8) for _ in range(3000))),
                       ("empty.png", b""), ("zeroes.png", png_bytes(0, 0, b""))]:
        write(j(name), data)
        write(j(name + ".mtl"), "newmtl m\nmap_Kd %s\n" % name)
        write(j(name + ".obj"), "mtllib %s.mtl\nusemtl m\n" % name + TRI_OBJ)
        add("png-bad-%s" % name, ["info", j(name + ".obj")], "error", "image|texture|read|png|size|empty", name)

    # deep recursion -------------------------------------------------------------------------------
    for n, expect in [(20000, "error"), (5000, "error"), (3000, "ok")]:
        doc = gltf_doc()
        doc["nodes"] = [{"children": [i + 1]} for i in range(n - 1)] + [{"mesh": 0}]
        write(j("chain%d.gltf" % n), json.dumps(doc))
        if expect == "error":
            add("deep-gltf-chain-%d" % n, ["info", j("chain%d.gltf" % n)], "error", "max-depth", "chain%d.gltf" % n)
        else:
            add("deep-gltf-chain-%d" % n, ["info", j("chain%d.gltf" % n)], "ok", r"graph:")
    for n in [40000, 3000, 1000]:
        protos = [{"name": "p%d" % i, "type": "instance", "target": "p%d" % (i + 1)} for i in range(n - 1)]
        protos.append({"name": "p%d" % (n - 1), "type": "mesh", "mesh": "t"})
        write(j("protochain%d.json" % n), json_scene([{"type": "instance", "target": "p0"}], prototypes=protos))
        if n > 2048:  # each prototype of the chain adds two levels: over 4096
            add("deep-json-prototypes-%d" % n, ["info", j("protochain%d.json" % n)], "error", "max-depth",
                "protochain%d.json" % n)
        else:
            add("deep-json-prototypes-%d" % n, ["info", j("protochain%d.json" % n)], "ok", "1 placements")
    for n in [100000, 5000]:
        write(j("nest%d.json" % n), "[" * n + "]" * n)
        add("deep-json-arrays-%d" % n, ["info", j("nest%d.json" % n)], "error", "max-depth|nest", "nest%d.json" % n)
        write(j("nestobj%d.json" % n), '{"a":' * n + "1" + "}" * n)
        add("deep-json-objects-%d" % n, ["info", j("nestobj%d.json" % n)], "error", "max-depth|nest", "nestobj%d.json" % n)
        write(j("nest%d.gltf" % n), '{"asset":{"version":"2.0"},"extras":' + "[" * n + "]" * n + "}")
        add("deep-gltf-arrays-%d" % n, ["info", j("nest%d.gltf" % n)], "error", "max-depth|nest|depth", "nest%d.gltf" % n)
    deep = '{"type": "group", "children": [' * 6000 + '{"type": "mesh", "mesh": "t"}' + "]}" * 6000
    write(j("groups6000.json"), json_scene(["@@"]).replace('"@@"', deep))
    add("deep-json-groups-6000", ["info", j("groups6000.json")], "error", "max-depth", "groups6000.json")
    add("deep-json-groups-max-depth-10", ["info", j("chain3000.gltf"), "--max-depth", "10"], "error", "max-depth",
        "chain3000.gltf")
    # glTF node cycle (child of itself, a two-node cycle)
    for name, nodes in [("selfchild", [{"children": [0], "mesh": 0}]),
                        ("cycle2", [{"children": [1]}, {"children": [0], "mesh": 0}])]:
        doc = gltf_doc()
        doc["nodes"] = nodes
        write(j(name + ".gltf"), json.dumps(doc))
        add("gltf-node-%s" % name, ["info", j(name + ".gltf")], "error", "cycle|parent|child|twice|more than one",
            name + ".gltf")
    # JSON instance cycles
    write(j("icycle.json"), json_scene([{"type": "instance", "target": "a"}], prototypes=[
        {"name": "a", "type": "instance", "target": "b"}, {"name": "b", "type": "instance", "target": "a"}]))
    add("json-instance-cycle", ["info", j("icycle.json")], "error", "cycle", "icycle.json")

    # huge fan-outs ---------------------------------------------------------------------------------
    for n, slow in [(10**6, True), (10**5, False)]:
        with open(j("fan%d.inst" % n), "w") as f:
            f.write("mesh tri.obj\n")
            for i in range(n):
                f.write("1 0 0 %d 0 1 0 %d 0 0 1 0\n" % (i % 1000, i // 1000))
        add("fanout-inst-%d" % n, ["info", j("fan%d.inst" % n)], "ok", r"%d placements" % n, slow=slow)
        add("fanout-inst-%d-limit" % n, ["info", j("fan%d.inst" % n), "--max-placements", "1000"], "error",
            "max-placements", "fan%d.inst" % n, slow=slow)
        add("fanout-inst-%d-trace" % n, ["trace", "--scene", j("fan%d.inst" % n), "--rays", j("one.rays"), "--query",
                                         "closest", "--out", j("out", "fan.hits"), "--threads", "2"], "ok", "rays|Mrays",
            slow=slow)
    write(j("mesh100k.json"), json_scene([{"type": "mesh", "mesh": "t"} for _ in range(10**5)]))
    add("fanout-json-100k-meshes", ["info", j("mesh100k.json")], "ok", r"100000 placements")
    add("fanout-json-100k-meshes-render", R + [j("mesh100k.json")], "ok", "")
    add("fanout-json-100k-meshes-limit", ["info", j("mesh100k.json"), "--max-placements", "99999"], "error",
        "max-placements", "mesh100k.json")
    write(j("inst100k.json"), json_scene([{"type": "instance", "target": "p", "translate": [i % 300, i // 300, 0]}
                                          for i in range(10**5)], prototypes=[{"name": "p", "type": "mesh", "mesh": "t"}]))
    add("fanout-json-100k-instances", ["info", j("inst100k.json")], "ok", r"100000 placements")
    # one OBJ referred to by 10^5 mesh nodes, and by 10^5 "meshes" entries: loaded once, its node tree
    # shared (one node per reference: root, the file's group, 10^5 groups, the OBJ's holder, group, mesh)
    write(j("fileref100k.json"), json_scene([{"type": "mesh", "mesh": "f"} for _ in range(10**5)],
                                            meshes=[{"name": "f", "file": "tri.obj"}]))
    add("fanout-json-file-100k-refs", ["info", j("fileref100k.json")], "ok",
        r"graph: 100005 nodes, 1 meshes(.|\n)*100000 placements")
    write(j("fileentries100k.json"), json_scene([{"type": "mesh", "mesh": "f%d" % i} for i in range(10**5)],
                                                meshes=[{"name": "f%d" % i, "file": "tri.obj"} for i in range(10**5)]))
    add("fanout-json-file-100k-entries", ["info", j("fileentries100k.json")], "ok",
        r"graph: 100005 nodes, 1 meshes(.|\n)*100000 placements")
    # scene files nesting references, 100 per level: nodes grow by one per reference, placements multiply and
    # are counted before any is made
    for lvl in range(5):
        inner = "tri.obj" if lvl == 0 else "fileref_L%d.json" % (lvl - 1)
        write(j("fileref_L%d.json" % lvl), json_scene(
            [{"type": "transform", "translate": [0, 0, k], "children": [{"type": "mesh", "mesh": "f"}]} for k in range(100)],
            meshes=[{"name": "f", "file": inner}]))
    add("fanout-json-file-nested-10^4", ["info", j("fileref_L1.json")], "ok",
        r"graph: 407 nodes, 1 meshes(.|\n)*10000 placements")
    add("fanout-json-file-nested-10^6", ["info", j("fileref_L2.json")], "ok", r"1000000 placements", slow=True)
    add("fanout-json-file-nested-10^10", ["info", j("fileref_L4.json")], "error",
        r"fileref_L4\.json: 10000000000 meshes, instances, cameras and lights at the top level exceed the limit of "
        r"4194304 \(--max-placements\)", "fileref_L4.json")
    add("fanout-json-file-nested-10^8-render", R + [j("fileref_L3.json")], "error", "--max-placements", "fileref_L3.json")
    # 10^5 usemtl (two materials alternating, and 10^5 distinct undefined ones)
    write(j("two.mtl"), "newmtl a\nKd 1 0 0\nnewmtl b\nKd 0 1 0\n")
    with open(j("usemtl100k.obj"), "w") as f:
        f.write("mtllib two.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\n")
        for i in range(10**5):
            f.write("usemtl %s\nf 1 2 3\n" % ("ab"[i % 2]))
    add("fanout-obj-100k-usemtl", ["info", j("usemtl100k.obj")], "ok", r"graph:")
    with open(j("usemtl100k_distinct.obj"), "w") as f:
        f.write("v 0 0 0\nv 1 0 0\nv 0 1 0\n")
        for i in range(10**5):
            f.write("usemtl m%d\nf 1 2 3\n" % i)
    # undefined materials are documented as the default material
    add("fanout-obj-100k-usemtl-undefined", ["info", j("usemtl100k_distinct.obj")], "ok", r"graph:")
    with open(j("usemtl100k_empty.obj"), "w") as f:
        f.write("mtllib two.mtl\n" + "usemtl a\nusemtl b\n" * 50000 + TRI_OBJ)
    add("fanout-obj-100k-usemtl-no-faces", ["info", j("usemtl100k_empty.obj")], "ok", r"graph:")
    # 10 per level, 7 deep (10^7 placements) and 8 deep (10^8)
    for depth, slow in [(7, True), (8, False), (5, False)]:
        protos = [{"name": "L0", "type": "mesh", "mesh": "t"}]
        for lvl in range(1, depth + 1):
            protos.append({"name": "L%d" % lvl, "type": "group", "children": [
                {"type": "instance", "target": "L%d" % (lvl - 1), "translate": [k, 0, 0]} for k in range(10)]})
        write(j("fan10x%d.json" % depth), json_scene([{"type": "instance", "target": "L%d" % depth}], prototypes=protos))
        if depth == 8:
            add("fanout-json-10^8", ["info", j("fan10x8.json")], "error", "max-placements", "fan10x8.json")
        elif depth == 7:
            add("fanout-json-10^7", ["info", j("fan10x7.json")], "error",
                "10000000 placements after flattening exceed the limit of 4194304 \\(--max-placements\\)", "fan10x7.json")
            add("fanout-json-10^7-limit", ["info", j("fan10x7.json"), "--max-placements", "1000000"], "error",
                "max-placements", "fan10x7.json")
        else:
            add("fanout-json-10^5-render", R + [j("fan10x5.json")], "ok", "")
    # many vertices / faces claimed by counts
    add("count-tri-limit", ["info", j("usemtl100k.obj"), "--max-triangles", "1000"], "error", "max-triangles",
        "usemtl100k.obj")

    # counts claimed by headers --------------------------------------------------------------------
    for cnt in [2 * 10**9, 2**31 - 1, 10**6]:
        write(j("offbin%d.off" % cnt), b"OFF BINARY\n" + struct.pack(">iii", cnt, cnt, 0) + b"\0" * 64)
        add("off-binary-count-%d" % cnt, ["info", j("offbin%d.off" % cnt)], "error",
            "limit|truncat|expect|bytes|short|vertices|count", "offbin%d.off" % cnt)
        write(j("offasc%d.off" % cnt), "OFF\n%d %d 0\n0 0 0\n" % (cnt, cnt))
        add("off-ascii-count-%d" % cnt, ["info", j("offasc%d.off" % cnt)], "error",
            "limit|truncat|expect|short|vertices|count|end", "offasc%d.off" % cnt)
        write(j("plybin%d.ply" % cnt), ply_binary(cnt, cnt))
        add("ply-binary-count-%d" % cnt, ["info", j("plybin%d.ply" % cnt)], "error",
            "limit|truncat|expect|bytes|short|vertices|count", "plybin%d.ply" % cnt)
        write(j("plyasc%d.ply" % cnt), PLY_ASCII.replace("vertex 3", "vertex %d" % cnt))
        add("ply-ascii-count-%d" % cnt, ["info", j("plyasc%d.ply" % cnt)], "error",
            "limit|truncat|expect|short|vertices|count|end", "plyasc%d.ply" % cnt)
        write(j("stlbin%d.stl" % cnt), stl_binary(cnt, 1))
        add("stl-binary-count-%d" % cnt, ["info", j("stlbin%d.stl" % cnt)], "error",
            "limit|truncat|expect|bytes|short|triangles|count|size", "stlbin%d.stl" % cnt)
    for tag, body in [("vertex", "0 0 0 9\n1 0 0\n0 1 0\n3 0 1 2\n"), ("face", "0 0 0\n1 0 0\n0 1 0\n3 0 1 2 2\n"),
                      ("joined", "0 0 0 1 0 0\n0 1 0\n3 0 1 2\n")]:
        write(j("plyextra_%s.ply" % tag), PLY_ASCII[:PLY_ASCII.index("end_header\n") + 11] + body)
        add("ply-extra-values-%s" % tag, ["info", j("plyextra_%s.ply" % tag)], "error", "more values on its line",
            "plyextra_%s.ply" % tag)
    write(j("plyneg.ply"), PLY_ASCII.replace("vertex 3", "vertex -3"))
    add("ply-negative-count", ["info", j("plyneg.ply")], "error", "count|vertex|negative|header|number", "plyneg.ply")
    write(j("offneg.off"), "OFF\n-3 1 0\n0 0 0\n")
    add("off-negative-count", ["info", j("offneg.off")], "error", "count|vertices|negative|header|number", "offneg.off")
    write(j("offface.off"), "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n2000000000 0 1 2\n")
    add("off-face-corner-count", ["info", j("offface.off")], "error", "corner|face|vertices|truncat|limit|count",
        "offface.off")
    write(j("offidx.off"), "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 99\n")
    add("off-index-out-of-range", ["info", j("offidx.off")], "error", "range|index|vertex", "offidx.off")
    write(j("plyidx.ply"), PLY_ASCII.replace("3 0 1 2\n", "3 0 1 -7\n"))
    add("ply-index-negative", ["info", j("plyidx.ply")], "error", "range|index|vertex", "plyidx.ply")

    # non-finite and overflowing numbers in every field ----------------------------------------------
    bad_numbers = ["nan", "inf", "-inf", "1e300", "-1e39"]
    for bi, b in enumerate(bad_numbers):
        for pos in range(3):
            coords = ["0", "0", "0"]
            coords[pos] = b
            name = "objv_%d_%d.obj" % (bi, pos)
            write(j(name), "v %s\nv 1 0 0\nv 0 1 0\nf 1 2 3\n" % " ".join(coords))
            add("nonfinite-obj-v-%s-%d" % (b, pos), ["info", j(name)], "error", "finite|overflow", name)
            add("nonfinite-obj-trace-%s-%d" % (b, pos), ["trace", "--scene", j(name), "--rays", j("one.rays"), "--query",
                                                           "closest", "--out", j("out", "h.hits")], "error",
                "finite|overflow", name)
        write(j("objvt_%d.obj" % bi), "vt %s 0\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1/1 2/1 3/1\n" % b)
        add("nonfinite-obj-vt-%s" % b, ["info", j("objvt_%d.obj" % bi)], "error", "finite|overflow", "objvt_%d.obj" % bi)
        write(j("objvn_%d.obj" % bi), "vn 0 %s 0\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1//1 2//1 3//1\n" % b)
        add("nonfinite-obj-vn-%s" % b, ["info", j("objvn_%d.obj" % bi)], "error", "finite|overflow", "objvn_%d.obj" % bi)
        write(j("mtlkd_%d.mtl" % bi), "newmtl m\nKd 1 %s 1\n" % b)
        write(j("mtlkd_%d.obj" % bi), "mtllib mtlkd_%d.mtl\nusemtl m\n" % bi + TRI_OBJ)
        add("nonfinite-mtl-kd-%s" % b, ["info", j("mtlkd_%d.obj" % bi)], "error", "finite|overflow", "mtlkd_%d.mtl" % bi)
        name = "ply_%d.ply" % bi
        write(j(name), PLY_ASCII.replace("1 0 0\n0 1 0\n3", "1 %s 0\n0 1 0\n3" % b))
        add("nonfinite-ply-%s" % b, ["info", j(name)], "error", "finite|overflow", name)
        name = "off_%d.off" % bi
        write(j(name), OFF_ASCII.replace("0 1 0\n3", "0 1 %s\n3" % b))
        add("nonfinite-off-%s" % b, ["info", j(name)], "error", "finite|overflow", name)
        name = "stl_%d.stl" % bi
        write(j(name), STL_ASCII.replace("vertex 1 0 0", "vertex 1 0 %s" % b))
        add("nonfinite-stl-%s" % b, ["info", j(name)], "error", "finite|overflow", name)
        pos = bi * 2 % 12
        m = ["1", "0", "0", "0", "0", "1", "0", "0", "0", "0", "1", "0"]
        m[pos] = b
        name = "inst_%d.inst" % bi
        write(j(name), "mesh tri.obj\n1 0 0 0 0 1 0 0 0 0 1 0\n%s\n" % " ".join(m))
        add("nonfinite-inst-%s-%d" % (b, pos), ["info", j(name)], "error", "finite|overflow", name)
    # binary non-finite values
    for val, tag in [(float("nan"), "nan"), (float("inf"), "inf")]:
        data = bytearray(ply_binary())
        hdr = data.index(b"end_header\n") + len(b"end_header\n")
        data[hdr + 16:hdr + 20] = struct.pack("<f", val)
        write(j("plybin_%s.ply" % tag), bytes(data))
        add("nonfinite-ply-binary-%s" % tag, ["info", j("plybin_%s.ply" % tag)], "error", "finite", "plybin_%s.ply" % tag)
        data = bytearray(stl_binary())
        data[84 + 12 + 4:84 + 12 + 8] = struct.pack("<f", val)
        write(j("stlbin_%s.stl" % tag), bytes(data))
        add("nonfinite-stl-binary-%s" % tag, ["info", j("stlbin_%s.stl" % tag)], "error", "finite", "stlbin_%s.stl" % tag)
        doc = gltf_doc((0, 0, 0, val, 0, 0, 0, 1, 0))
        write(j("gltf_%s.gltf" % tag), json.dumps(doc).replace("NaN", "0").replace("Infinity", "0"))
        doc = gltf_doc((0, 0, 0, val, 0, 0, 0, 1, 0))
        doc["accessors"][0].pop("min")
        doc["accessors"][0].pop("max")
        write(j("gltf_%s.gltf" % tag), json.dumps(doc))
        add("nonfinite-gltf-positions-%s" % tag, ["info", j("gltf_%s.gltf" % tag)], "error", "finite",
            "gltf_%s.gltf" % tag)
        ray = struct.pack("<8f", val, 0.2, 1, 0, 0, 0, -1, val)
        write(j("rays_%s.rays" % tag), ray * 4)
        add("nonfinite-rays-%s" % tag, ["trace", "--scene", j("tri.obj"), "--rays", j("rays_%s.rays" % tag), "--query",
                                        "closest", "--out", j("out", "nf.hits")], "ok", "rays|Mrays")
    # JSON: a huge number (1e400 reads as inf) in every numeric field
    base_tri = {"name": "t", "positions": [0, 0, 0, 1, 0, 0, 0, 1, 0], "uvs": [0, 0, 1, 0, 0, 1], "indices": [0, 1, 2]}
    fields = [
        ("translate", lambda v: ([{"type": "transform", "translate": [0, v, 0], "children": [{"type": "mesh", "mesh": "t"}]}],
                                 None, None)),
        ("rotate-angle", lambda v: ([{"type": "transform", "rotate": [v, 0, 1, 0], "children": [{"type": "mesh", "mesh": "t"}]}],
                                    None, None)),
        ("rotate-axis", lambda v: ([{"type": "transform", "rotate": [30, 0, v, 0], "children": [{"type": "mesh", "mesh": "t"}]}],
                                   None, None)),
        ("scale", lambda v: ([{"type": "transform", "scale": v, "children": [{"type": "mesh", "mesh": "t"}]}], None, None)),
        ("scale3", lambda v: ([{"type": "transform", "scale": [1, 1, v], "children": [{"type": "mesh", "mesh": "t"}]}],
                              None, None)),
        ("matrix", lambda v: ([{"type": "transform", "matrix": [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, v],
                                "children": [{"type": "mesh", "mesh": "t"}]}], None, None)),
        ("instance-translate", lambda v: ([{"type": "instance", "target": "p", "translate": [v, 0, 0]}], None,
                                          [{"name": "p", "type": "mesh", "mesh": "t"}])),
        ("camera-eye", lambda v: ([{"type": "mesh", "mesh": "t"}, {"type": "camera", "eye": [0, v, 5]}], None, None)),
        ("camera-target", lambda v: ([{"type": "mesh", "mesh": "t"}, {"type": "camera", "target": [v, 0, 0]}], None, None)),
        ("camera-up", lambda v: ([{"type": "mesh", "mesh": "t"}, {"type": "camera", "up": [0, v, 0]}], None, None)),
        ("camera-fovy", lambda v: ([{"type": "mesh", "mesh": "t"}, {"type": "camera", "fovy": v}], None, None)),
        ("light-direction", lambda v: ([{"type": "mesh", "mesh": "t"}, {"type": "light", "light": "directional",
                                                                         "direction": [v, 1, 0]}], None, None)),
        ("positions", lambda v: ([{"type": "mesh", "mesh": "t"}], [dict(base_tri, positions=[0, 0, 0, v, 0, 0, 0, 1, 0])],
                                 None)),
        ("uvs", lambda v: ([{"type": "mesh", "mesh": "t"}], [dict(base_tri, uvs=[0, 0, v, 0, 0, 1])], None)),
        ("indices", lambda v: ([{"type": "mesh", "mesh": "t"}], [dict(base_tri, indices=[0, 1, v])], None)),
        ("colour", lambda v: ([{"type": "mesh", "mesh": "t"}], [dict(base_tri, material="m")], None, [{"name": "m", "colour": [v, 0, 0]}])),
        ("alphaCutoff", lambda v: ([{"type": "mesh", "mesh": "t"}], [dict(base_tri, material="m")], None,
                                   [{"name": "m", "texture": "ok.png", "alphaMode": "MASK", "alphaCutoff": v}])),
        ("instance-id", lambda v: ([{"type": "instance", "target": "p", "id": v}], None,
                                   [{"name": "p", "type": "mesh", "mesh": "t"}])),
    ]
    for fname, make in fields:
        for vi, v in enumerate(["1e400", "-1e400", "1e39"]):
            parts = make("@@")
            nodes, meshes, protos = parts[0], parts[1], parts[2]
            mats = parts[3] if len(parts) > 3 else None
            text = json_scene(nodes, meshes=meshes, prototypes=protos, materials=mats).replace('"@@"', v)
            name = "jsonnum_%s_%d.json" % (fname, vi)
            write(j(name), text)
            pattern = "finite|overflow|range|float|integer|whole|number"
            add("nonfinite-json-%s-%s" % (fname, v), R + [j(name)] if fname.startswith("camera") else ["info", j(name)],
                "error", pattern, name)
    # glTF numeric fields: 1e400 in node transforms, camera, material factors
    gfields = [
        ("translation", lambda d: d["nodes"][0].update(translation=[0, "@@", 0])),
        ("scale", lambda d: d["nodes"][0].update(scale=[1, "@@", 1])),
        ("rotation", lambda d: d["nodes"][0].update(rotation=[0, 0, 0, "@@"])),
        ("matrix", lambda d: d["nodes"][0].update(matrix=[1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, "@@", 0, 0, 1])),
        ("yfov", lambda d: (d.update(cameras=[{"type": "perspective", "perspective": {"yfov": "@@", "znear": 0.1}}]),
                            d["nodes"].append({"camera": 0}), d["scenes"][0]["nodes"].append(1))),
        ("baseColorFactor", lambda d: (d.update(materials=[{"pbrMetallicRoughness": {"baseColorFactor": [1, "@@", 1, 1]}}]),
                                       d["meshes"][0]["primitives"][0].update(material=0))),
        ("alphaCutoff", lambda d: (d.update(materials=[{"alphaMode": "MASK", "alphaCutoff": "@@"}]),
                                   d["meshes"][0]["primitives"][0].update(material=0))),
        ("accessor-count", lambda d: d["accessors"][0].update(count="@@")),
        ("byteOffset", lambda d: d["bufferViews"][0].update(byteOffset="@@")),
    ]
    for fname, mutate in gfields:
        for vi, v in enumerate(["1e400", "-1e400"]):
            doc = gltf_doc()
            mutate(doc)
            name = "gltfnum_%s_%d.gltf" % (fname, vi)
            write(j(name), json.dumps(doc).replace('"@@"', v))
            add("nonfinite-gltf-%s-%s" % (fname, v), R + [j(name)] if fname == "yfov" else ["info", j(name)], "error",
                "finite|overflow|range|float|integer|whole|number|positive|expected", name)

    # degenerate cameras and transforms ---------------------------------------------------------------
    # an up hint parallel to the view is documented as no error (the fallback up is used)
    for cname, cam in [("up-parallel", {"type": "camera", "eye": [0.2, 0.2, 5], "target": [0.2, 0.2, 0], "up": [0, 0, 1]}),
                       ("up-parallel-neg", {"type": "camera", "eye": [0.2, 5, 0.2], "target": [0.2, 0, 0.2],
                                            "up": [0, -3, 0]})]:
        write(j("cam_%s.json" % cname), json_scene([{"type": "mesh", "mesh": "t"}, cam]))
        add("camera-%s" % cname, R + [j("cam_%s.json" % cname)], "ok", "")
    cams = [
        ("up-zero", {"type": "camera", "up": [0, 0, 0]}),
        ("eye-is-target", {"type": "camera", "eye": [1, 2, 3], "target": [1, 2, 3]}),
        ("eye-near-target", {"type": "camera", "eye": [1, 2, 3], "target": [1, 2, 3.0000000001]}),
        ("fovy-0", {"type": "camera", "fovy": 0}),
        ("fovy-180", {"type": "camera", "fovy": 180}),
        ("fovy-neg", {"type": "camera", "fovy": -10}),
    ]
    for cname, cam in cams:
        name = "cam_%s.json" % cname
        write(j(name), json_scene([{"type": "mesh", "mesh": "t"}, cam]))
        add("camera-%s" % cname, R + [j(name)], "error", "camera|fovy", name)
    for sname, scale in [("1e-30", 1e-30), ("1e-38", 1e-38), ("0", 0), ("1e30", 1e30)]:
        name = "camscale_%s.json" % sname
        write(j(name), json_scene([{"type": "mesh", "mesh": "t"},
                                   {"type": "transform", "scale": scale, "children": [{"type": "camera"}]}]))
        add("camera-under-scale-%s" % sname, R + [j(name)], "error", "camera|transform|invert|singular|finite", name)
    for depth, s in [(2, 1e30), (3, 1e20), (2, 1e-30), (5, 1e10)]:
        node = {"type": "mesh", "mesh": "t"}
        for _ in range(depth):
            node = {"type": "transform", "scale": s, "children": [node]}
        name = "nestscale_%d_%g.json" % (depth, s)
        write(j(name), json_scene([node]))
        add("transform-nested-scale-%dx%g" % (depth, s), ["info", j(name)], "error",
            "finite|invert|float|singular|range|overflow", name)
        # the same through instances
        protos = [{"name": "q0", "type": "mesh", "mesh": "t"}]
        for k in range(1, depth + 1):
            protos.append({"name": "q%d" % k, "type": "instance", "target": "q%d" % (k - 1), "scale": s})
        name = "nestinst_%d_%g.json" % (depth, s)
        write(j(name), json_scene([{"type": "instance", "target": "q%d" % depth}], prototypes=protos))
        add("instance-nested-scale-%dx%g" % (depth, s), R + [j(name)], "error",
            "finite|invert|float|singular|range|overflow", name)
    for sname, sc in [("0", 0), ("[1,0,1]", [1, 0, 1]), ("1e-39", 1e-39), ("[1e-30,1e30,1]", [1e-30, 1e30, 1e-50])]:
        name = "instsing_%d.json" % len(sname)
        write(j(name), json_scene([{"type": "instance", "target": "p", "scale": sc}],
                                  prototypes=[{"name": "p", "type": "mesh", "mesh": "t"}]))
        add("instance-singular-scale-%s" % sname, ["info", j(name)], "error", "invert|singular", name)
        name = "xfsing_%d.json" % len(sname)
        write(j(name), json_scene([{"type": "transform", "scale": sc, "children": [{"type": "mesh", "mesh": "t"}]}]))
        add("transform-singular-scale-%s" % sname, ["info", j(name)], "error", "invert|singular", name)
    write(j("instzero.inst"), "mesh tri.obj\n0 0 0 0 0 0 0 0 0 0 0 0\n")
    add("inst-singular", ["info", j("instzero.inst")], "error", "singular", "instzero.inst")
    add("inst-singular-trace", ["trace", "--scene", j("instzero.inst"), "--rays", j("one.rays"), "--query", "closest",
                                "--out", j("out", "h.hits")], "error", "singular", "instzero.inst")
    write(j("rank2.inst"), "mesh tri.obj\n1 0 0 0 0 1 0 0 1 1 0 0\n")
    add("inst-rank-2", ["info", j("rank2.inst")], "error", "singular", "rank2.inst")
    doc = gltf_doc()
    doc["nodes"][0]["scale"] = [0, 0, 0]
    write(j("gltfscale0.gltf"), json.dumps(doc))
    add("gltf-scale-0", ["info", j("gltfscale0.gltf")], "error", "invert|singular", "gltfscale0.gltf")
    doc = gltf_doc()
    doc["nodes"][0]["rotation"] = [0, 0, 0, 0]
    write(j("gltfrot0.gltf"), json.dumps(doc))
    add("gltf-rotation-zero-quaternion", ["info", j("gltfrot0.gltf")], "error", "rotation|quaternion|unit",
        "gltfrot0.gltf")

    # .inst oddities ----------------------------------------------------------------------------------
    write(j("self.inst"), "mesh self.inst\n1 0 0 0 0 1 0 0 0 0 1 0\n")
    add("inst-names-itself", ["info", j("self.inst")], "error", "itself", "self.inst")
    write(j("selfdot.inst"), "mesh ./selfdot.inst\n1 0 0 0 0 1 0 0 0 0 1 0\n")
    add("inst-names-itself-dot", ["info", j("selfdot.inst")], "error", "itself|inst", "selfdot.inst")
    write(j("other.inst"), "mesh self2.inst\n1 0 0 0 0 1 0 0 0 0 1 0\n")
    write(j("self2.inst"), "mesh other.inst\n1 0 0 0 0 1 0 0 0 0 1 0\n")
    add("inst-names-inst", ["info", j("other.inst")], "error", "inst|obj|mesh|face|itself", "inst")
    write(j("noinst.inst"), "# nothing\nmesh tri.obj\n")
    add("inst-no-instances", ["info", j("noinst.inst")], "error", "no instance", "noinst.inst")
    add("inst-no-instances-trace", ["trace", "--scene", j("noinst.inst"), "--rays", j("one.rays"), "--query", "closest",
                                    "--out", j("out", "h.hits")], "error", "no instance", "noinst.inst")
    write(j("nofaces.obj"), "v 0 0 0\nv 1 0 0\nv 0 1 0\n")
    write(j("nofaces.inst"), "mesh nofaces.obj\n1 0 0 0 0 1 0 0 0 0 1 0\n")
    add("inst-mesh-without-faces", ["info", j("nofaces.inst")], "error", "no .*f|face|nothing", "nofaces.obj")
    add("obj-without-faces", ["info", j("nofaces.obj")], "error", "face|nothing|triangle", "nofaces.obj")
    add("obj-without-faces-trace", ["trace", "--scene", j("nofaces.obj"), "--rays", j("one.rays"), "--query", "closest",
                                    "--out", j("out", "h.hits")], "error", "face|nothing|triangle", "nofaces.obj")
    write(j("nomesh.inst"), "1 0 0 0 0 1 0 0 0 0 1 0\n")
    add("inst-no-mesh-line", ["info", j("nomesh.inst")], "error", "mesh", "nomesh.inst")
    write(j("twomesh.inst"), "mesh tri.obj\nmesh tri.obj\n1 0 0 0 0 1 0 0 0 0 1 0\n")
    add("inst-two-mesh-lines", ["info", j("twomesh.inst")], "error", "mesh", "twomesh.inst")
    for n in [11, 13, 0]:
        write(j("inst%dnums.inst" % n), "mesh tri.obj\n" + " ".join(["1"] * n) + (" x" if n == 0 else "") + "\n")
        add("inst-%d-numbers" % n, ["info", j("inst%dnums.inst" % n)], "error", "12 numbers|number", "inst%dnums.inst" % n)
    write(j("missingmesh.inst"), "mesh nowhere.obj\n1 0 0 0 0 1 0 0 0 0 1 0\n")
    add("inst-missing-mesh", ["info", j("missingmesh.inst")], "error", "not found", "nowhere.obj")
    write(j("empty.obj"), "")
    add("obj-empty", ["info", j("empty.obj")], "error", "face|nothing|empty|triangle", "empty.obj")
    write(j("empty.json"), "")
    add("json-empty", ["info", j("empty.json")], "error", "json|empty|expected|end", "empty.json")
    write(j("emptyscene.json"), '{"version": 1}')
    add("json-no-nodes", ["info", j("emptyscene.json")], "error", "nothing|empty|no ", "emptyscene.json")

    # random bytes, UTF-16, binary as text --------------------------------------------------------------
    for ext in ["obj", "json", "gltf", "glb", "ply", "off", "stl", "inst", "om"]:
        for seed in range(2):
            r2 = random.Random(seed * 100 + len(ext))
            name = "random%d.%s" % (seed, ext)
            write(j(name), bytes(r2.getrandbits(8) for _ in range(200 + 3000 * seed)))
            add("random-bytes-%s-%d" % (ext, seed), ["info", j(name)], "error",
                ".", name)
    for ext, text in [("obj", TRI_OBJ), ("json", json_scene([{"type": "mesh", "mesh": "t"}])), ("inst",
                      "mesh tri.obj\n1 0 0 0 0 1 0 0 0 0 1 0\n"), ("ply", PLY_ASCII), ("off", OFF_ASCII),
                      ("stl", STL_ASCII), ("gltf", json.dumps(gltf_doc()))]:
        for enc, tag in [("utf-16", "bom"), ("utf-16-le", "le"), ("utf-32", "u32")]:
            name = "utf16_%s.%s" % (tag, ext)
            write(j(name), text.encode(enc))
            add("utf16-%s-%s" % (tag, ext), ["info", j(name)], "error", "utf|NUL|text|byte|json|header|magic|format|read",
                name)
    # a NUL in the middle of an otherwise valid OBJ, MTL, .inst
    write(j("nulmid.obj"), TRI_OBJ + "\0" + TRI_OBJ)
    add("nul-in-obj", ["info", j("nulmid.obj")], "error", "NUL", "nulmid.obj")
    write(j("nulmtl.mtl"), "newmtl m\n\0Kd 1 1 1\n")
    write(j("nulmtl.obj"), "mtllib nulmtl.mtl\nusemtl m\n" + TRI_OBJ)
    add("nul-in-mtl", ["info", j("nulmtl.obj")], "error", "NUL", "nulmtl.mtl")

    # 10 MB tokens (messages must stay short) ------------------------------------------------------------
    big = "x" * (10 * 2**20)
    digits = "1" * (10 * 2**20)
    for tag, text in [("v-coord", "v 1 2 %s\n" % big), ("v-digits", "v 1 2 %s\n" % digits),
                      ("f-index", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 %s\n" % digits),
                      ("usemtl", "usemtl %s\n" % big + TRI_OBJ), ("mtllib", "mtllib %s\n" % big + TRI_OBJ),
                      ("keyword", big + " 1 2 3\n" + TRI_OBJ), ("line-no-newline", TRI_OBJ + "v " + big)]:
        name = "bigtoken_%s.obj" % tag
        write(j(name), text)
        if tag in ("usemtl", "keyword"):   # an undefined material, an unknown statement: documented as accepted
            add("token-10MB-obj-%s" % tag, ["info", j(name)], "ok", "graph:")
        else:
            add("token-10MB-obj-%s" % tag, ["info", j(name)], "error", ".", name)
    add("token-10MB-obj-trace", ["trace", "--scene", j("bigtoken_v-coord.obj"), "--rays", j("one.rays"), "--query",
                                 "closest", "--out", j("out", "h.hits")], "error", ".", "bigtoken_v-coord.obj")
    write(j("bigtoken.inst"), "mesh tri.obj\n1 0 0 0 0 1 0 0 0 0 1 %s\n" % big)
    add("token-10MB-inst", ["info", j("bigtoken.inst")], "error", ".", "bigtoken.inst")
    write(j("bigtoken_mesh.inst"), "mesh %s\n1 0 0 0 0 1 0 0 0 0 1 0\n" % big)
    add("token-10MB-inst-mesh", ["info", j("bigtoken_mesh.inst")], "error", ".", "bigtoken_mesh.inst")
    write(j("bigtoken_key.json"), '{"version": 1, "%s": 1}' % big)
    add("token-10MB-json-key", ["info", j("bigtoken_key.json")], "error", ".", "bigtoken_key.json")
    write(j("bigtoken_str.json"), json_scene([{"type": "mesh", "mesh": big}]))
    add("token-10MB-json-string", ["info", j("bigtoken_str.json")], "error", ".", "bigtoken_str.json")
    write(j("bigtoken_num.json"), json_scene([{"type": "mesh", "mesh": "t"}]).replace('"version": 1', '"version": ' + digits))
    add("token-10MB-json-number", ["info", j("bigtoken_num.json")], "error", ".", "bigtoken_num.json")
    write(j("bigtoken_file.json"), json_scene([{"type": "mesh", "mesh": "m"}], meshes=[{"name": "m", "file": big + ".obj"}]))
    add("token-10MB-json-file", ["info", j("bigtoken_file.json")], "error", ".", "bigtoken_file.json")
    doc = gltf_doc()
    doc["buffers"][0]["uri"] = big + ".bin"
    write(j("bigtoken_uri.gltf"), json.dumps(doc))
    add("token-10MB-gltf-uri", ["info", j("bigtoken_uri.gltf")], "error", ".", "bigtoken_uri.gltf")
    write(j("bigtoken.ply"), PLY_ASCII.replace("property float z", "property float " + big))
    add("token-10MB-ply-property", ["info", j("bigtoken.ply")], "error", ".", "bigtoken.ply")
    add("token-10MB-cli-scene", ["info", big[:100000] + ".obj"], "error", ".", None)
    add("token-10MB-cli-size", ["render", "-o", out, j("tri.obj"), "--size", digits[:100000]], "error", "--size",
        "--size", codes=(2,))

    # non-convex faces of more than 256 corners (fanned and reported) --------------------------------------
    for n in [257, 300, 1000]:
        pts = []
        for k in range(n):
            a = 2 * 3.141592653589793 * k / n
            rad = 1.0 if k % 2 == 0 else 0.5
            pts.append((rad * __import__("math").cos(a), rad * __import__("math").sin(a), 0))
        name = "comb%d.obj" % n
        write(j(name), "".join("v %.9f %.9f %.9f\n" % p for p in pts) + "f " + " ".join(str(k + 1) for k in range(n)) + "\n")
        add("nonconvex-obj-%d" % n, ["info", j(name)], "ok", "fanned")
        name = "comb%d.off" % n
        write(j(name), "OFF\n%d 1 0\n" % n + "".join("%.9f %.9f %.9f\n" % p for p in pts) + "%d " % n +
              " ".join(str(k) for k in range(n)) + "\n")
        add("nonconvex-off-%d" % n, ["info", j(name)], "ok", "fanned")
    add("nonconvex-obj-render", R + [j("comb300.obj")], "ok", "")

    # glTF schema violations ---------------------------------------------------------------------------------
    def gmut(name, mutate, pattern):
        doc = gltf_doc()
        mutate(doc)
        write(j(name + ".gltf"), json.dumps(doc))
        add("gltf-schema-%s" % name, ["info", j(name + ".gltf")], "error", pattern, name + ".gltf")

    def with_tex(d, index):
        uv = struct.pack("<6f", 0, 0, 1, 0, 0, 1)
        d["buffers"].append({"byteLength": 24, "uri": "data:application/octet-stream;base64," + base64.b64encode(uv).decode()})
        d["bufferViews"].append({"buffer": 1, "byteLength": 24})
        d["accessors"].append({"bufferView": 1, "componentType": 5126, "count": 3, "type": "VEC2"})
        d["meshes"][0]["primitives"][0]["attributes"]["TEXCOORD_0"] = 1
        d["images"] = [{"uri": "ok.png"}]
        d["textures"] = [{"source": 0}]
        d["materials"] = [{"pbrMetallicRoughness": {"baseColorTexture": {"index": index}}}]
        d["meshes"][0]["primitives"][0]["material"] = 0
    gmut("texture-index-neg", lambda d: with_tex(d, -1), "textures|index|range")
    gmut("texture-index-big", lambda d: with_tex(d, 5), "textures|index|range")
    gmut("texture-index-float", lambda d: with_tex(d, 0.5), "integer|whole|index")
    gmut("texture-index-string", lambda d: with_tex(d, "0"), "integer|number|expected")
    gmut("pbr-array", lambda d: (d.update(materials=[{"pbrMetallicRoughness": []}]),
                                 d["meshes"][0]["primitives"][0].update(material=0)), "expected an object")
    gmut("material-index-big", lambda d: d["meshes"][0]["primitives"][0].update(material=3), "material|range|index")
    gmut("accessor-count-over", lambda d: d["accessors"][0].update(count=1000), "accessor|range|bytes|buffer|exceed")
    gmut("accessor-count-huge", lambda d: d["accessors"][0].update(count=2**40), "accessor|range|bytes|buffer|exceed|limit")
    gmut("accessor-index-big", lambda d: d["meshes"][0]["primitives"][0]["attributes"].update(POSITION=9),
         "accessor|range|index")
    gmut("accessor-index-neg", lambda d: d["meshes"][0]["primitives"][0]["attributes"].update(POSITION=-1),
         "accessor|range|index")
    gmut("accessor-type-wrong", lambda d: d["accessors"][0].update(type="SCALAR"), "VEC3|type|POSITION")
    gmut("accessor-component-bogus", lambda d: d["accessors"][0].update(componentType=1234), "componentType|component")
    gmut("accessor-offset-huge", lambda d: d["accessors"][0].update(byteOffset=2**62), "range|offset|bytes|buffer|exceed")
    gmut("bufferview-huge-length", lambda d: d["bufferViews"][0].update(byteLength=2**40), "range|buffer|bytes|exceed")
    gmut("bufferview-stride-huge", lambda d: d["bufferViews"][0].update(byteStride=10**9), "stride|range|byteStride")
    gmut("bufferview-buffer-big", lambda d: d["bufferViews"][0].update(buffer=4), "buffer|range|index")
    gmut("buffer-length-lie", lambda d: d["buffers"][0].update(byteLength=10**12), "byteLength|length|bytes|buffer")
    gmut("buffer-uri-missing", lambda d: d["buffers"][0].update(uri="nothere.bin"), "not found|nothere")
    gmut("buffer-uri-bad-base64", lambda d: d["buffers"][0].update(uri="data:application/octet-stream;base64,@@@@"),
         "base64|uri|data")
    gmut("node-mesh-big", lambda d: d["nodes"][0].update(mesh=7), "mesh|range|index")
    gmut("scene-node-big", lambda d: d["scenes"][0].update(nodes=[42]), "node|range|index")
    gmut("scene-index-big", lambda d: d.update(scene=9), "scene|range|index")
    gmut("node-children-big", lambda d: d["nodes"][0].update(children=[99]), "node|range|index|children")
    gmut("indices-out-of-range", lambda d: (d["accessors"].append({"bufferView": 0, "componentType": 5125, "count": 6,
                                                                   "type": "SCALAR"}),
                                            d["meshes"][0]["primitives"][0].update(indices=1)), "index|range|vertex|indices")
    gmut("asset-missing", lambda d: d.pop("asset"), "asset")
    gmut("version-3", lambda d: d["asset"].update(version="3.0"), "version")
    gmut("mode-bogus", lambda d: d["meshes"][0]["primitives"][0].update(mode=99), "mode")
    gmut("primitives-object", lambda d: d["meshes"][0].update(primitives={}), "expected an array|primitives")
    gmut("nodes-string", lambda d: d.update(nodes="x"), "expected an array|nodes")
    gmut("image-missing", lambda d: (with_tex(d, 0), d["images"][0].update(uri="nothere.png")), "not found|nothere")
    gmut("image-source-big", lambda d: (with_tex(d, 0), d["textures"][0].update(source=8)), "source|image|range|index")
    gmut("required-extension", lambda d: d.update(extensionsRequired=["KHR_draco_mesh_compression"]), "extension|draco")
    # GLB damage: each fault named by the header, the chunk or the buffer, with the sizes at stake
    doc = gltf_doc()
    good = glb_bytes(doc)
    size = len(good)
    bin_doc = dict(doc, buffers=[{"byteLength": 36}])
    with_bin = glb_bytes(bin_doc, struct.pack("<9f", 0, 0, 0, 1, 0, 0, 0, 1, 0))
    json_end = 20 + struct.unpack("<I", with_bin[12:16])[0]
    def relength(data):
        return data[:8] + struct.pack("<I", len(data)) + data[12:]
    for tag, data, pattern in [
            ("length-lie", good[:8] + struct.pack("<I", 10**9) + good[12:],
             r"GLB header: length 1000000000 runs past the end of the file \(%d bytes\)" % size),
            ("length-short", good + b"    ", r"GLB header: length %d ends before the end of the file \(%d bytes\)" % (size, size + 4)),
            ("chunk-length-lie", good[:12] + struct.pack("<I", 10**9) + good[16:],
             r"chunk 0: length 1000000000 runs past the end of the file \(%d bytes\)" % size),
            ("bad-magic", b"glTx" + good[4:], r"GLB header: magic is 'glTx', expected 'glTF'"),
            ("json-as-glb", json.dumps(doc).encode(), r"GLB header: magic is '\{\"as', expected 'glTF'"),
            ("binary-magic", b"\x89PNG" + good[4:], r"GLB header: magic is '\\x89PNG', expected 'glTF'"),
            ("version-1", good[:4] + struct.pack("<I", 1) + good[8:], r"GLB header: version is 1, expected 2"),
            ("header-only", good[:12], r"GLB header: length %d runs past the end of the file \(12 bytes\)" % size),
            ("header-alone", relength(good[:12]), r"GLB header: no chunk follows the header"),
            ("tiny", good[:7], r"GLB header: the file has 7 bytes, fewer than the header's 12"),
            ("bin-first", good[:16] + b"BIN\0" + good[20:], r"chunk 0: type is 'BIN\\x00', expected 'JSON'"),
            ("bin-length-lie", with_bin[:json_end] + struct.pack("<I", 99999) + with_bin[json_end + 4:],
             r"chunk 1: length 99999 runs past the end of the file \(%d bytes\)" % len(with_bin)),
            ("bin-cut", relength(with_bin[:json_end + 4]),
             r"chunk 1: its 8-byte header at byte %d runs past the end of the file" % json_end),
            ("bin-missing", glb_bytes(bin_doc), r"buffers\[0\]: has no uri and the file has no BIN chunk"),
            ("bin-short", relength(with_bin[:json_end] + struct.pack("<I", 8) + b"BIN\0" + b"\0" * 8),
             r"buffers\[0\]: byteLength 36 is more than the 8 bytes of the BIN chunk")]:
        write(j("glb_%s.glb" % tag), data)
        add("glb-%s" % tag, ["info", j("glb_%s.glb" % tag)], "error", pattern, "glb_%s.glb" % tag)
    # a chunk of an unknown type after BIN is skipped, as glTF asks
    write(j("glb_extra-chunk.glb"), relength(with_bin + struct.pack("<I", 4) + b"XTRA" + b"abcd"))
    add("glb-extra-chunk", ["info", j("glb_extra-chunk.glb")], "ok", r"1 meshes")
    write(j("gltf_no-uri.gltf"), json.dumps(bin_doc))
    add("glb-gltf-buffer-without-uri", ["info", j("gltf_no-uri.gltf")], "error",
        r"buffers\[0\]: has no uri \(only the first buffer of a \.glb file", "gltf_no-uri.gltf")

    # truncated files of each format --------------------------------------------------------------------------
    bases = {"ply": PLY_ASCII.encode(), "plyb": ply_binary(), "off": OFF_ASCII.encode(), "stl": STL_ASCII.encode(),
             "stlb": stl_binary(1, 1), "gltf": json.dumps(gltf_doc()).encode(),
             "json": json_scene([{"type": "mesh", "mesh": "t"}]).encode(), "glb": glb_bytes(gltf_doc()),
             "png": small_png()}
    ext = {"plyb": "ply", "stlb": "stl"}
    for fmt, data in bases.items():
        for frac in [0.05, 0.3, 0.6, 0.95]:
            cut = max(1, int(len(data) * frac))
            if fmt in ("ply", "off") and data[cut - 1:cut] == b"\n":
                cut -= 1
            name = "trunc_%s_%d.%s" % (fmt, int(frac * 100), ext.get(fmt, fmt))
            write(j(name), data[:cut])
            if fmt == "png":
                write(j(name + ".mtl"), "newmtl m\nmap_Kd %s\n" % name)
                write(j(name + ".obj"), "mtllib %s.mtl\nusemtl m\n" % name + TRI_OBJ)
                add("truncated-%s-%d%%" % (fmt, frac * 100), ["info", j(name + ".obj")], "error", ".", name)
            else:
                add("truncated-%s-%d%%" % (fmt, frac * 100), ["info", j(name)], "error", ".", name)
    # text formats without counts: truncated mid-line
    for tag, text in [("obj-face", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2"), ("obj-vertex", "v 0 0 0\nv 1 0 0\nv 0 1\nf 1 2 3\n"),
                      ("obj-index", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 -"), ("obj-slash", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3/")]:
        write(j("trunc_%s.obj" % tag), text)
        add("truncated-%s" % tag, ["info", j("trunc_%s.obj" % tag)], "error", ".", "trunc_%s.obj" % tag)
    write(j("trunc.inst"), "mesh tri.obj\n1 0 0 0 0 1 0 0 0 0 1")
    add("truncated-inst", ["info", j("trunc.inst")], "error", "12 numbers", "trunc.inst")
    for n in [1, 31, 33, 65]:
        write(j("trunc%d.rays" % n), b"\0" * n)
        add("truncated-rays-%d" % n, ["trace", "--scene", j("tri.obj"), "--rays", j("trunc%d.rays" % n), "--query",
                                      "closest", "--out", j("out", "h.hits")], "error", "32", "trunc%d.rays" % n)
    write(j("empty.rays"), b"")
    add("rays-empty", ["trace", "--scene", j("tri.obj"), "--rays", j("empty.rays"), "--query", "closest", "--out",
                       j("out", "h.hits")], "error", "no rays|empty|nothing", "empty.rays")

    # the command line's numbers -------------------------------------------------------------------------------
    for opt, vals in [("--size", ["64x48junk", "0x8", "8x0", "-8x8", "8x", "x8", "8X8", "99999x99999", "16384x16384",
                                  "8x8x8", " 8x8", "0x10"]),
                      ("--spp", ["1e9", "4294967297", "0", "-1", "65537", "1.5", "nan", "0x10", "+1"]),
                      ("--threads", ["2x", "0", "-1", "1025", "18446744073709551617", "inf"]),
                      ("--exposure", ["nan", "inf", "1e400", "31", "-31", "1x"]),
                      ("--max-texels", ["junk", "-1", "1e9", "18446744073709551616"]),
                      ("--max-depth", ["-5", "x"]), ("--max-file-bytes", ["1.5", ""]),
                      ("--max-triangles", ["2^28"]), ("--max-placements", ["1,000"])]:
        for k, v in enumerate(vals):
            add("cli-%s-%d" % (opt[2:], k), R + [j("tri.obj"), opt, v], "error", re.escape(opt), opt, codes=(2,))
    add("cli-ao-radius-nan", R + [j("tri.obj"), "--kernel", "ao", "--ao-radius", "nan"], "error", "--ao-radius",
        "--ao-radius", codes=(2,))
    add("cli-ao-radius-neg", R + [j("tri.obj"), "--kernel", "ao", "--ao-radius", "-1%"], "error", "--ao-radius",
        "--ao-radius", codes=(2,))
    add("cli-trace-threads", ["trace", "--scene", j("tri.obj"), "--rays", j("one.rays"), "--query", "closest", "--out",
                              j("out", "h.hits"), "--threads", "2x"], "error", "--threads", "--threads", codes=(2,))
    add("cli-unknown-option", ["info", j("tri.obj"), "--frobnicate"], "error", "unknown", "--frobnicate", codes=(2,))
    add("cli-twice", R + [j("tri.obj"), "--spp", "1", "--spp", "2"], "error", "more than once", "--spp", codes=(2,))
    add("cli-missing-value", R + [j("tri.obj"), "--spp"], "error", "needs a value", "--spp", codes=(2,))
    add("cli-unknown-command", ["frobnicate"], "error", "unknown|command", "frobnicate", codes=(2,))
    add("cli-gen-unknown", ["info", "gen:nothing"], "error", "generator|nothing", "nothing")
    add("cli-gen-bad-param", ["info", "gen:sphere:subdivisions=1e9"], "error", "subdivisions", "subdivisions")
    add("cli-gen-huge", ["info", "gen:sphere:subdivisions=30"], "error", "subdivisions|limit|max", "subdivisions")
    add("cli-gen-terrain-huge", ["info", "gen:terrain:resolution=1000000000"], "error", "resolution|limit|max",
        "resolution")
    add("cli-gen-soup-huge", ["info", "gen:triangle_soup:count=1000000000000"], "error", "count|limit|max|triangles",
        "count")

    # generator parameters: non-finite, negative, huge, unknown
    for spec, param in [("sphere:radius=nan", "radius"), ("sphere:radius=1e39", "radius"), ("sphere:radius=0", "radius"),
                        ("sphere:radius=-1", "radius"), ("sphere:subdivisions=-1", "subdivisions"),
                        ("sphere:bogus=1", "bogus"), ("terrain:size=nan", "size"), ("terrain:resolution=0", "resolution"),
                        ("terrain:resolution=70000", "resolution"), ("terrain:amplitude=inf", "amplitude"),
                        ("terrain:octaves=1000000", "octaves"), ("terrain:seed=-1", "seed"),
                        ("triangle_soup:count=0", "count"), ("triangle_soup:count=-5", "count"),
                        ("triangle_soup:size=nan", "size"), ("triangle_soup:extent=1e39", "extent"),
                        ("billboard_forest:billboards=1000000000000", "billboards"),
                        ("billboard_forest:spheres=-1", "spheres"),
                        ("billboard_forest:texture_size=100000", "texture_size")]:
        add("gen-param-%s" % spec.replace(":", "-").replace("=", "-"), ["info", "gen:" + spec], "error", param, param,
            codes=(1, 2))
    add("gen-param-render-radius-nan", R + ["gen:sphere:radius=nan"], "error", "radius", "radius", codes=(1, 2))

    # images of other formats claiming huge sizes (checked before decoding)
    for name, data in [("huge.ppm", b"P6\n100000 100000\n255\n" + b"\0" * 1000),
                       ("huge.pgm", b"P5\n2000000000 3\n255\n" + b"\0" * 1000),
                       ("huge.tga", struct.pack("<BBBHHBHHHHBB", 0, 0, 2, 0, 0, 0, 0, 0, 65535, 65535, 32, 8) + b"\0" * 1000),
                       ("huge.hdr", b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 100000 +X 100000\n" + b"\0" * 1000),
                       ("huge.bmp", b"BM" + struct.pack("<IHHI", 1000, 0, 0, 54) + struct.pack("<IiiHHIIiiII", 40, 100000,
                                                                                                 100000, 1, 24, 0, 0, 0, 0, 0, 0)
                        + b"\0" * 1000),
                       ("huge.gif", b"GIF89a" + struct.pack("<HHBBB", 65535, 65535, 0, 0, 0) + b"\0" * 100)]:
        write(j(name), data)
        write(j(name + ".mtl"), "newmtl m\nmap_Kd %s\n" % name)
        write(j(name + ".obj"), "mtllib %s.mtl\nusemtl m\n" % name + TRI_OBJ)
        add("image-huge-%s" % name, ["info", j(name + ".obj")], "error", "texels|image", name)

    # files referring to themselves or to each other
    write(j("selfmesh.json"), json_scene([{"type": "mesh", "mesh": "m"}], meshes=[{"name": "m", "file": "selfmesh.json"}]))
    add("json-mesh-file-itself", ["info", j("selfmesh.json")], "error", "itself|cycle|already|refer|loading",
        "selfmesh.json")
    write(j("ping.json"), json_scene([{"type": "mesh", "mesh": "m"}], meshes=[{"name": "m", "file": "pong.json"}]))
    write(j("pong.json"), json_scene([{"type": "mesh", "mesh": "m"}], meshes=[{"name": "m", "file": "ping.json"}]))
    add("json-mesh-file-cycle", ["info", j("ping.json")], "error", "itself|cycle|already|refer|loading", "ping.json")
    write(j("selfmtl.obj"), "mtllib selfmtl.obj\n" + TRI_OBJ)
    add("obj-mtllib-itself", ["info", j("selfmtl.obj")], "ok", "graph:")   # an MTL reader ignores OBJ statements
    write(j("gltfself.gltf"), json.dumps(dict(gltf_doc(), buffers=[{"byteLength": 36, "uri": "gltfself.gltf"}])))
    add("gltf-buffer-is-itself", ["info", j("gltfself.gltf")], "error", "byteLength", "gltfself.gltf")
    # OBJ indices and corners
    for tag, text, pattern in [("index-0", "f 1 2 0\n", "range|0"), ("index-neg-huge", "f 1 2 -99999999999\n", "range"),
                               ("index-huge", "f 1 2 99999999999999999999\n", "range|integer|index"),
                               ("vt-range", "f 1/9 2/9 3/9\n", "range"), ("vn-range", "f 1//9 2//9 3//9\n", "range")]:
        write(j("objidx_%s.obj" % tag), "v 0 0 0\nv 1 0 0\nv 0 1 0\n" + text)
        add("obj-%s" % tag, ["info", j("objidx_%s.obj" % tag)], "error", pattern, "objidx_%s.obj" % tag)
    write(j("objmillion.obj"), "v 0 0 0\nv 1 0 0\nv 0 1 0\nf " + " ".join(["1 2 3"] * 333333) + "\n")
    add("obj-face-of-a-million-corners", ["info", j("objmillion.obj")], "ok", "fanned")   # winds round 333333 times
    for n in [5, 7, 301]:   # stars {n/2}: every turn the same way, self-intersecting: fanned and reported
        pts = [(__import__("math").cos(2 * 3.141592653589793 * 2 * k / n),
                __import__("math").sin(2 * 3.141592653589793 * 2 * k / n), 0) for k in range(n)]
        write(j("star%d.obj" % n), "".join("v %.9f %.9f %.9f\n" % q for q in pts) + "f " +
              " ".join(str(k + 1) for k in range(n)) + "\n")
        add("nonconvex-star-%d" % n, ["info", j("star%d.obj" % n)], "ok", "fanned")
    # MTL oddities
    for tag, mtl, pattern in [("map-missing", "newmtl m\nmap_Kd nothere.png\n", "not found"),
                              ("map-d-missing", "newmtl m\nmap_d nothere.png\n", "not found"),
                              ("map-option-nan", "newmtl m\nmap_Kd -s nan nan nan ok.png\n", "finite|nan|option"),
                              ("map-folder", "newmtl m\nmap_Kd folder.d\n", "folder"),
]:
        write(j("mtl_%s.mtl" % tag), mtl)
        write(j("mtl_%s.obj" % tag), "mtllib mtl_%s.mtl\nusemtl m\nvt 0 0\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1/1 2/1 3/1\n" % tag)
        add("mtl-%s" % tag, ["info", j("mtl_%s.obj" % tag)], "error", pattern, "mtl_%s" % tag)
    write(j("mtl_twice.mtl"), "newmtl m\nKd 1 0 0\nnewmtl m\nKd 0 1 0\n")   # documented: the first definition wins
    write(j("mtl_twice.obj"), "mtllib mtl_twice.mtl\nusemtl m\n" + TRI_OBJ)
    add("mtl-newmtl-twice", ["info", j("mtl_twice.obj")], "ok", "graph:")
    # glTF cameras
    for tag, cam in [("yfov-0", {"type": "perspective", "perspective": {"yfov": 0, "znear": 0.1}}),
                     ("yfov-4", {"type": "perspective", "perspective": {"yfov": 4, "znear": 0.1}}),
                     ("aspect-neg", {"type": "perspective", "perspective": {"yfov": 1, "znear": 0.1, "aspectRatio": -1}}),
                     ("znear-0", {"type": "perspective", "perspective": {"yfov": 1, "znear": 0}}),
                     ("no-perspective", {"type": "perspective"}),
                     ("type-bogus", {"type": "fisheye"})]:
        doc = gltf_doc()
        doc["cameras"] = [cam]
        doc["nodes"].append({"camera": 0, "translation": [0.2, 0.2, 3]})
        doc["scenes"][0]["nodes"].append(1)
        write(j("gcam_%s.gltf" % tag), json.dumps(doc))
        add("gltf-camera-%s" % tag, R + [j("gcam_%s.gltf" % tag)], "error", "camera|yfov|znear|aspect|perspective|type",
            "gcam_%s.gltf" % tag)
    doc = gltf_doc()
    doc["cameras"] = [{"type": "perspective", "perspective": {"yfov": 1, "znear": 0.1}}]
    doc["nodes"].append({"camera": 0, "scale": [0, 0, 0]})
    doc["scenes"][0]["nodes"].append(1)
    write(j("gcam_scale0.gltf"), json.dumps(doc))
    add("gltf-camera-scale-0", R + [j("gcam_scale0.gltf")], "error", "camera|invert|singular", "gcam_scale0.gltf")

    # outputs -------------------------------------------------------------------------------------------------------
    add("out-dev-full-trace", ["trace", "--scene", j("tri.obj"), "--rays", j("one.rays"), "--query", "closest", "--out",
                               "/dev/full"], "error", "space|full|write", "/dev/full")
    write(j("afile"), "x")
    add("out-folder-is-file", ["render", "--size", "8x8", "-o", j("afile"), j("tri.obj")], "error", ".", "afile")
    add("out-folder-under-file", ["render", "--size", "8x8", "-o", j("afile", "sub"), j("tri.obj")], "error", ".", "afile")
    add("out-folder-proc", ["render", "--size", "8x8", "-o", "/proc/canopy_out", j("tri.obj")], "error", ".",
        "/proc/canopy_out")
    add("out-trace-folder", ["trace", "--scene", j("tri.obj"), "--rays", j("one.rays"), "--query", "closest", "--out",
                             j("folder.d")], "error", ".", "folder.d")
    add("out-trace-missing-dir", ["trace", "--scene", j("tri.obj"), "--rays", j("one.rays"), "--query", "closest",
                                  "--out", j("nodir", "h.hits")], "error", ".", "nodir")
    add("out-png-is-folder", ["render", "--size", "8x8", "-o", j("outpng"), j("tri.obj")], "error", ".", "tri.png",
        codes=(1,))
    os.makedirs(j("outpng", "tri.png"))

    # size limits of files -----------------------------------------------------------------------------------------
    add("file-over-max-file-bytes", ["info", j("usemtl100k.obj"), "--max-file-bytes", "1000"], "error",
        "max-file-bytes", "usemtl100k.obj")
    add("texture-over-max-file-bytes", ["info", j("huge_16384x16384.png.obj"), "--max-file-bytes", "100000"], "error",
        "max-file-bytes", "huge_16384x16384.png")
    add("rays-over-max-file-bytes", ["trace", "--scene", j("tri.obj"), "--rays", j("rays_nan.rays"), "--query",
                                     "closest", "--out", j("out", "h.hits"), "--max-file-bytes", "64"], "error",
        "max-file-bytes", "rays_nan.rays")
    # unknown extension, missing file
    write(j("scene.xyz"), "x")
    add("unknown-extension", ["info", j("scene.xyz")], "error", "extension", "scene.xyz")
    add("missing-scene", ["info", j("nothere.obj")], "error", "not found", "nothere.obj")
    add("missing-scene-render", R + [j("nothere.json")], "error", "not found", "nothere.json")
    # valid controls (the battery's baseline must succeed)
    add("control-obj", ["info", j("tri.obj")], "ok", "graph:")
    add("control-obj-render", R + [j("tri.obj")], "ok", "")
    for fmt in ["ply", "off", "stl"]:
        write(j("ctrl.%s" % fmt), {"ply": PLY_ASCII, "off": OFF_ASCII, "stl": STL_ASCII}[fmt])
        add("control-%s" % fmt, ["info", j("ctrl.%s" % fmt)], "ok", "graph:")
    write(j("ctrlb.ply"), ply_binary())
    add("control-ply-binary", ["info", j("ctrlb.ply")], "ok", "graph:")
    write(j("ctrlb.stl"), stl_binary())
    add("control-stl-binary", ["info", j("ctrlb.stl")], "ok", "graph:")
    write(j("ctrl.gltf"), json.dumps(gltf_doc()))
    add("control-gltf", ["info", j("ctrl.gltf")], "ok", "graph:")
    write(j("ctrl.glb"), glb_bytes(gltf_doc()))
    add("control-glb", ["info", j("ctrl.glb")], "ok", "graph:")
    write(j("ctrl.json"), json_scene([{"type": "mesh", "mesh": "t"}, {"type": "camera", "eye": [0.3, 0.3, 3]}]))
    add("control-json-render", R + [j("ctrl.json")], "ok", "")
    write(j("ctrl.inst"), "mesh tri.obj\n1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 2 0 1 0 0 0 0 1 0\n")
    add("control-inst-trace", ["trace", "--scene", j("ctrl.inst"), "--rays", j("one.rays"), "--query", "closest",
                               "--out", j("out", "c.hits")], "ok", "rays|Mrays")
    write(j("ctrltex.mtl"), "newmtl m\nmap_Kd ok.png\n")
    write(j("ctrltex.obj"), "mtllib ctrltex.mtl\nusemtl m\nvt 0 0\nvt 1 0\nvt 0 1\nv 0 0 0\nv 1 0 0\nv 0 1 0\n"
                            "f 1/1 2/2 3/3\n")
    add("control-obj-texture-render", R + [j("ctrltex.obj")], "ok", "")


# ---- running and classifying -----------------------------------------------------------------

def run_case(case, canopy, limit_kib, timeout_s):
    args = [canopy] + case.args
    limit = "ulimit -v %d; " % limit_kib if limit_kib > 0 else ""   # 0: no limit (AddressSanitizer builds)
    cmd = limit + "exec timeout -k 5 %d \"$@\"" % timeout_s
    t0 = time.monotonic()
    p = subprocess.run(["bash", "-c", cmd, "hostile"] + args, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                       stdin=subprocess.DEVNULL)
    dt = time.monotonic() - t0
    out = p.stdout.decode("utf-8", "replace")
    err = p.stderr.decode("utf-8", "replace")
    rc = p.returncode
    long_line = max((len(l) for l in (out + "\n" + err).split("\n")), default=0)
    if rc == 124 or rc == 137 and dt >= timeout_s:
        return "hang", rc, dt, "over %d s" % timeout_s
    if re.search(r"bad_alloc|out of memory|cannot allocate|std::length_error", err, re.I):
        return "limit", rc, dt, first_line(err)
    if rc < 0 or rc >= 128 or re.search(r"Sanitizer|runtime error:|terminate called|Assertion", err):
        return "crash", rc, dt, first_line(err) or "signal %d" % (rc - 128 if rc >= 128 else -rc)
    if long_line > MAX_LINE:
        return "silent", rc, dt, "an output line of %d characters" % long_line
    kinds = case.expect.split("|")
    if rc == 0 and "ok" in kinds:
        if case.pattern and not re.search(case.pattern, out, re.I):
            return "silent", rc, dt, "success without /%s/ in the output" % case.pattern
        return "ok", rc, dt, first_line(out.strip().split("\n")[-1] if out.strip() else "")
    if rc == 0:
        return "silent", rc, dt, "exit 0 where an error is due"
    if "error" not in kinds:
        return "silent", rc, dt, "error where success is due: " + first_line(err)
    if rc not in case.codes:
        return "silent", rc, dt, "exit %d, expected %s: %s" % (rc, case.codes, first_line(err))
    msg = err.strip().split("\n")[0] if err.strip() else ""
    if case.names is not None and case.names not in err:
        return "silent", rc, dt, "the message does not name %r: %s" % (case.names[:40], first_line(err))
    if case.pattern and not re.search(case.pattern, err, re.I):
        return "silent", rc, dt, "the message does not match /%s/: %s" % (case.pattern, first_line(err))
    return "ok", rc, dt, msg[:MAX_LINE]


def first_line(text):
    text = text.strip()
    return text.split("\n")[0][:200] if text else ""


def main():
    ap = argparse.ArgumentParser(description="Run a generated battery of hostile inputs through canopy.")
    ap.add_argument("filters", nargs="*", help="run only cases whose name contains one of these words")
    ap.add_argument("--quick", action="store_true", help="the first case of each group, none of the slow ones")
    ap.add_argument("--canopy", default=os.path.join(ROOT, "build", "release", "tools", "canopy"))
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--limit-kib", type=int, default=4 * 1024 * 1024, help="ulimit -v in KiB (default 4 GiB; 0: none)")
    ap.add_argument("--timeout", type=int, default=30)
    ap.add_argument("--keep", action="store_true", help="keep the generated folder")
    ap.add_argument("--verbose", "-v", action="store_true", help="print the message of every case")
    a = ap.parse_args()
    canopy = os.path.abspath(a.canopy)
    if not os.access(canopy, os.X_OK):
        print("hostile_inputs: %s is not an executable (build the release preset first)" % canopy, file=sys.stderr)
        return 2
    d = tempfile.mkdtemp(prefix="canopy_hostile_")
    t0 = time.monotonic()
    try:
        build(d, canopy)
        cases = [c for c in CASES if not (a.quick and c.slow) and
                 (not a.filters or any(f in c.name for f in a.filters))]
        if a.quick:  # the first case of each group (the name up to its second '-')
            seen = {}
            quick = []
            for c in cases:
                group = "-".join(c.name.split("-")[:2])
                seen[group] = seen.get(group, 0) + 1
                if seen[group] == 1:
                    quick.append(c)
            cases = quick
        names = [c.name for c in CASES]
        dup = {n for n in names if names.count(n) > 1}
        if dup:
            print("hostile_inputs: duplicate case names: %s" % sorted(dup), file=sys.stderr)
            return 2
        print("hostile_inputs: %d cases (of %d), generated in %.1f s in %s; ulimit -v %d KiB, timeout %d s" %
              (len(cases), len(CASES), time.monotonic() - t0, d, a.limit_kib, a.timeout))
        counts = {k: 0 for k in ["ok", "crash", "hang", "limit", "silent"]}
        with concurrent.futures.ThreadPoolExecutor(max_workers=a.jobs) as pool:
            futures = [pool.submit(run_case, c, canopy, a.limit_kib, a.timeout) for c in cases]
            for c, f in zip(cases, futures):
                cls, rc, dt, why = f.result()
                counts[cls] += 1
                if cls != "ok" or a.verbose:
                    print("%-6s %-44s exit %-3d %5.2f s  %s" % (cls.upper(), c.name, rc, dt, why), flush=True)
                else:
                    print("ok     %-44s exit %-3d %5.2f s" % (c.name, rc, dt), flush=True)
        print()
        print("| class | cases |")
        print("| --- | --- |")
        labels = [("ok", "ok (expected outcome)"), ("crash", "crashes"), ("hang", "hangs"),
                  ("limit", "over the limit (memory)"), ("silent", "silent acceptances / unclear errors")]
        for k, label in labels:
            print("| %s | %d |" % (label, counts[k]))
        print("| total | %d (%.0f s) |" % (len(cases), time.monotonic() - t0))
        return 0 if counts["ok"] == len(cases) else 1
    finally:
        if a.keep:
            print("kept %s" % d)
        else:
            shutil.rmtree(d, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
