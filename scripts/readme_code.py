#!/usr/bin/env python3
"""The README's C++ code, checked: every ```cpp block compiles, or is kept identical to a source
file that the build compiles.

Each ```cpp block of README.md follows an HTML comment (invisible on GitHub) saying how:

  <!-- compiled: program -->           a whole program: compiled and linked against the installed
                                       package and run (exit status 0) by scripts/consumer_check.sh
  <!-- compiled: translation unit -->  compiled, not linked, against the installed package
  <!-- compiled: lines of PATH -->     every code line of the block (comments, blank lines and
                                       indentation aside) is a line of PATH, in the same order;
                                       PATH (relative to the project root) is compiled by the build.
                                       For code of modules the package does not install
                                       (canopy.scene, canopy.plugins).

  readme_code.py check [README]       checks the markers and the 'lines of' blocks (a ctest test)
  readme_code.py write DIR [README]   checks, then writes the compiled blocks into DIR with
                                      DIR/blocks.cmake (targets, included by examples/consumer)
                                      and DIR/programs.txt (the programs to run)
"""
import pathlib
import re
import sys

MARKER = re.compile(r"^<!--\s*compiled:\s*(.*?)\s*-->\s*$")


class ReadmeError(Exception):
    pass


def blocks(readme):
    """(line number of the fence, marker text or None, code lines) for each ```cpp block."""
    lines = readme.read_text(encoding="utf-8").splitlines()
    found = []
    i = 0
    while i < len(lines):
        if lines[i].strip() == "```cpp":
            start = i + 1
            marker = None
            j = i - 1
            while j >= 0 and lines[j].strip() == "":
                j -= 1
            if j >= 0:
                m = MARKER.match(lines[j].strip())
                marker = m.group(1) if m else None
            k = start
            while k < len(lines) and lines[k].strip() != "```":
                k += 1
            if k == len(lines):
                raise ReadmeError(f"{readme.name}:{start}: ```cpp block is not closed")
            found.append((start, marker, lines[start:k]))
            i = k + 1
        else:
            i += 1
    return found


def code_of(line):
    """A line without its // comment and surrounding blanks ('' for comment-only lines)."""
    return re.sub(r"(^|\s)//.*$", "", line).strip()


def check_lines_of(readme, start, lines, path, root):
    source = root / path
    if not source.is_file():
        raise ReadmeError(f"{readme.name}:{start}: 'lines of {path}': no such file")
    wanted = [(start + 1 + n, code_of(l)) for n, l in enumerate(lines)]
    have = [code_of(l) for l in source.read_text(encoding="utf-8").splitlines()]
    pos = 0
    for number, code in wanted:
        if not code:
            continue
        try:
            pos = have.index(code, pos) + 1
        except ValueError:
            raise ReadmeError(f"{readme.name}:{number}: not a line of {path} (in this order): {code[:80]}")


def check(readme, root):
    checked = []
    for start, marker, lines in blocks(readme):
        if marker is None:
            raise ReadmeError(f"{readme.name}:{start}: ```cpp block without a '<!-- compiled: ... -->' marker "
                              "(program, translation unit, or lines of PATH)")
        if marker in ("program", "translation unit"):
            checked.append((start, marker, lines))
        elif marker.startswith("lines of "):
            check_lines_of(readme, start, lines, marker[len("lines of "):].strip(), root)
        else:
            raise ReadmeError(f"{readme.name}:{start}: unknown marker 'compiled: {marker}'")
    return checked


def write(readme, root, out):
    out.mkdir(parents=True, exist_ok=True)
    cmake = ["# Written by scripts/readme_code.py from README.md: its compiled C++ blocks, with the project's",
             "# warnings as errors.",
             "set(readme_warnings -Wall -Wextra -Wpedantic -Wshadow -Wconversion -Wno-sign-conversion -Werror)"]
    programs = []
    for start, marker, lines in check(readme, root):
        name = f"readme_line_{start}"
        source = out / f"{name}.cpp"
        source.write_text(f"// README.md, the block at line {start} ({marker}).\n" + "\n".join(lines) + "\n",
                          encoding="utf-8")
        if marker == "program":
            cmake.append(f'add_executable({name} "{source.resolve()}")')
            cmake.append(f"target_link_libraries({name} PRIVATE canopy::canopy canopy::canopy_procedural canopy::canopy_cpu_guard)")
            cmake.append(f"target_compile_options({name} PRIVATE ${{readme_warnings}})")
            programs.append(name)
        else:
            cmake.append(f'add_library({name} OBJECT "{source.resolve()}")')
            cmake.append(f"target_link_libraries({name} PRIVATE canopy::canopy canopy::canopy_procedural)")
            cmake.append(f"target_compile_options({name} PRIVATE ${{readme_warnings}})")
    (out / "blocks.cmake").write_text("\n".join(cmake) + "\n", encoding="utf-8")
    (out / "programs.txt").write_text("".join(p + "\n" for p in programs), encoding="utf-8")
    return programs


def main(argv):
    root = pathlib.Path(__file__).resolve().parent.parent
    try:
        if len(argv) >= 2 and argv[1] == "check":
            readme = pathlib.Path(argv[2]) if len(argv) > 2 else root / "README.md"
            n = len(blocks(readme))
            check(readme, root)
            print(f"readme: {n} C++ blocks, each compiled or a copy of compiled source")
        elif len(argv) >= 3 and argv[1] == "write":
            readme = pathlib.Path(argv[3]) if len(argv) > 3 else root / "README.md"
            programs = write(readme, root, pathlib.Path(argv[2]))
            print(f"readme: blocks written to {argv[2]} ({len(programs)} programs)")
        else:
            print(__doc__, file=sys.stderr)
            return 2
    except ReadmeError as e:
        print(f"readme: {e}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
