#!/usr/bin/python3
"""Writes the generated tables of tests/README.md from the tests that check them.

Each table between `<!-- table:NAME:begin ... -->` and `<!-- table:NAME:end -->`
is printed by one test (or a suite): run with HAPTICPD_PRINT_TABLE=1, it prints
every case it checked as a markdown row (tests/readme_table.h). This script runs
those tests, and replaces each table's rows (its header lines stay) with the
rows printed, in the order printed. A test that fails writes nothing.

    /usr/bin/python3 tests/update_tables.py [BUILD_DIR]          # rewrite
    /usr/bin/python3 tests/update_tables.py [BUILD_DIR] --check  # diff, exit 1

BUILD_DIR is build/release unless given. The ctest readme.tables_current runs
the --check mode.
"""

import argparse
import difflib
import os
import re
import subprocess
import sys
from pathlib import Path

from readme_markers import marked_blocks  # tests/readme_markers.py, beside this file

SOURCE_DIR = Path(__file__).resolve().parent.parent

# NAME: (test binary under BUILD_DIR/tests, --gtest_filter)
TABLES = {
    "cli": ("cli_tests", "CliTest.BadInputTable"),
    "scene-files": ("server_tests", "SceneFileParse.BadFilesNameKeyAndFile"),
    "state-directory": ("server_tests", "Store.StateDirectoryTable"),
    "services": ("server_tests", "BadInputTable.*"),
}

MARKER = re.compile(r"^<!-- table:([A-Za-z0-9_-]+):(begin|end)\b.*-->\s*$")
SEPARATOR = re.compile(r"^\|(\s*:?-+:?\s*\|)+\s*$")


def printed_rows(build_dir, name):
    binary, gtest_filter = TABLES[name]
    path = build_dir / "tests" / binary
    if not path.is_file():
        sys.exit(f"update_tables: {path}: not found (build the tests first)")
    env = dict(os.environ, HAPTICPD_PRINT_TABLE="1")
    run = subprocess.run(
        [str(path), f"--gtest_filter={gtest_filter}", "--gtest_color=no"],
        env=env,
        cwd=SOURCE_DIR,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        errors="replace",
    )
    if run.returncode != 0:
        sys.stderr.write(run.stdout)
        sys.exit(f"update_tables: table '{name}': {binary} --gtest_filter={gtest_filter} "
                 f"failed (exit {run.returncode}): its rows are not written")
    rows = [line for line in run.stdout.splitlines() if line.startswith("| ")]
    if not rows:
        sys.exit(f"update_tables: table '{name}': {binary} --gtest_filter={gtest_filter} "
                 f"printed no rows")
    return rows


def regenerate(text, build_dir):
    """The README with every marked table's rows as the tests print them."""
    lines = text.split("\n")
    blocks, problems = marked_blocks(lines, MARKER)
    problems += [f"line {b + 1}: no test prints table '{name}' (known: {', '.join(TABLES)})"
                 for name, (b, _) in blocks.items() if name not in TABLES]
    missing = set(TABLES) - set(blocks)
    if missing:
        problems.append(f"no markers for table(s) {', '.join(sorted(missing))}")
    if problems:
        sys.exit("update_tables: " + "\n  ".join(problems))
    # From the last block up, so that earlier line indices stay valid.
    for name, (b, e) in sorted(blocks.items(), key=lambda kv: -kv[1][0]):
        body = lines[b + 1:e]
        sep = next((k for k, line in enumerate(body) if SEPARATOR.match(line)), None)
        if sep is None:
            sys.exit(f"update_tables: line {b + 1}: table '{name}' has no header (|---|) line")
        trailing = len(body)
        while trailing > sep + 1 and not body[trailing - 1].strip():
            trailing -= 1
        lines[b + 1:e] = body[:sep + 1] + printed_rows(build_dir, name) + body[trailing:]
    return "\n".join(lines)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("build_dir", nargs="?", default="build/release",
                        help="the build folder holding tests/*_tests (default build/release)")
    parser.add_argument("--check", action="store_true",
                        help="change nothing; exit 1 with a diff when the README differs")
    parser.add_argument("--readme", default=str(SOURCE_DIR / "tests" / "README.md"))
    args = parser.parse_args()
    readme = Path(args.readme)
    old = readme.read_text(encoding="utf-8")
    new = regenerate(old, Path(args.build_dir).resolve())
    if old == new:
        print(f"update_tables: the tables of {readme} are current")
        return 0
    if args.check:
        sys.stdout.writelines(difflib.unified_diff(
            old.splitlines(keepends=True), new.splitlines(keepends=True),
            f"{readme} (as committed)", f"{readme} (as the tests print it)"))
        print(f"update_tables: the tables of {readme} differ from what the tests check; "
              f"run /usr/bin/python3 tests/update_tables.py and commit the result")
        return 1
    readme.write_text(new, encoding="utf-8")
    print(f"update_tables: rewrote the tables of {readme}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
