#!/usr/bin/env python3
"""Each plugin's documentation is written once, in the head comment of its source file;
docs/scene/NAME.md is made from it, and checked by ctest to be what the source says.

The head comment is the file's leading block of // lines. Its first paragraph names the module
(for the reader of the code); the documentation is the rest of the block from its first
'// ###' heading on, with the '// ' taken off each line. For the run-time example plugin the
page ends with the plugin's whole source (the file after its head comment) as a C++ listing.

  plugin_docs.py check [ROOT]   the pages are what the sources say (a ctest test)
  plugin_docs.py write [ROOT]   writes the pages from the sources
"""
import difflib
import pathlib
import sys

# page (docs/scene/...) → the source whose head comment documents it; True: append the source.
PAGES = {
    "bench.md": ("plugins/bench/bench_plugin.cppm", False),
    "gltf.md": ("plugins/gltf/gltf_plugin.cppm", False),
    "json.md": ("plugins/json/json_plugin.cppm", False),
    "obj.md": ("plugins/obj/obj_plugin.cppm", False),
    "openmesh.md": ("plugins/openmesh/openmesh_plugin.cppm", False),
    "procedural.md": ("plugins/procedural/procedural_plugin.cppm", False),
    "plugins.md": ("plugins/runtime_example/spiral_plugin.cpp", True),
}


class DocsError(Exception):
    pass


def page_of(source):
    """The documentation page written in the head comment of `source`."""
    lines = source.read_text(encoding="utf-8").splitlines()
    head = 0
    while head < len(lines) and lines[head].startswith("//"):
        head += 1
    comment = [line[3:] if line.startswith("// ") else line[2:] for line in lines[:head]]
    start = next((i for i, line in enumerate(comment) if line.startswith("###")), None)
    if start is None:
        raise DocsError(f"{source}: its head comment has no '// ###' heading (the start of its documentation)")
    return "\n".join(comment[start:]).rstrip("\n") + "\n", lines[head:]


def expected(root, name):
    source, with_listing = PAGES[name]
    text, code = page_of(root / source)
    if with_listing:
        while code and code[0].strip() == "":
            code = code[1:]
        text += "\n```cpp\n" + "\n".join(code).rstrip("\n") + "\n```\n"
    return text


def main(argv):
    if len(argv) < 2 or argv[1] not in ("check", "write"):
        print(__doc__, file=sys.stderr)
        return 2
    root = pathlib.Path(argv[2]) if len(argv) > 2 else pathlib.Path(__file__).resolve().parent.parent
    failed = False
    try:
        for name in PAGES:
            want = expected(root, name)
            page = root / "docs" / "scene" / name
            if argv[1] == "write":
                page.write_text(want, encoding="utf-8")
                continue
            have = page.read_text(encoding="utf-8") if page.exists() else ""
            if have != want:
                failed = True
                print(f"docs/scene/{name} is not what the head comment of {PAGES[name][0]} says "
                      f"(run scripts/plugin_docs.py write):", file=sys.stderr)
                sys.stderr.writelines(difflib.unified_diff(have.splitlines(True), want.splitlines(True),
                                                           f"docs/scene/{name}", PAGES[name][0], n=1))
    except DocsError as e:
        print(e, file=sys.stderr)
        return 1
    if not failed and argv[1] == "check":
        print(f"{len(PAGES)} plugin pages are their sources' head comments")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
