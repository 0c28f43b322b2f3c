#!/usr/bin/env bash
# Hostile-input battery for the canopy command line: generates malformed, huge, deep,
# special-file and degenerate inputs in a temporary folder and runs each through `canopy info`,
# `render` or `trace` under `ulimit -v` (4 GiB) and `timeout` (30 s); each case has an expected
# outcome (an error naming the file and the problem, or a success) and is classified ok, crash,
# hang, limit (out of memory) or silent (wrong success, unclear error, overlong message line).
# Prints one line per case and a summary table; exits 1 if any case is not ok.
#   scripts/hostile_inputs.sh [--quick] [--canopy PATH] [--jobs N] [--limit-kib N] [--timeout S]
#                             [--keep] [-v] [FILTER...]
# --quick runs the first case of each group, no slow one (under a minute on 2 cores; ctest runs
# it, label `hostile`);
# FILTER words run only the cases whose name contains one of them. Details: hostile_inputs.py.
exec python3 "$(dirname "$0")/hostile_inputs.py" "$@"
