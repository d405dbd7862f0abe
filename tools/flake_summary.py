"""The flake summary of ./hil rehearse: which tests failed (or errored) in which pass.

usage: python tools/flake_summary.py PASS1.xml PASS2.xml ...  (pytest's JUnit XML files)

Each argument is one pass: a JUnit file, or several joined by commas.
Prints every test that did not pass in some pass, by name, with the passes it failed in; a
test that failed in some passes and passed in others is a flake, one that failed in every
pass fails outright. Exit 0 when no test failed in any pass, 1 when one did, 2 when a pass
left no readable JUnit file (that pass's verdict is unknown, so it is not a green one).
"""

from __future__ import annotations

import sys
import xml.etree.ElementTree as ET
from pathlib import Path


def failed_tests(path: Path) -> tuple[set[str], int]:
    """(names of the tests that failed or errored, number of tests run) in one JUnit file."""
    root = ET.parse(path).getroot()
    failed: set[str] = set()
    run = 0
    for case in root.iter("testcase"):
        run += 1
        if case.find("failure") is not None or case.find("error") is not None:
            failed.add(f"{case.get('classname', '')}::{case.get('name', '')}")
    return failed, run


def main(argv: list[str]) -> int:
    if not argv:
        print(__doc__.strip().splitlines()[2], file=sys.stderr)
        return 2
    per_pass: list[set[str]] = []
    unreadable = False
    for i, name in enumerate(argv, 1):
        # one pass may be several JUnit files, joined by commas (./hil test's two runs)
        failed, run = set(), 0
        try:
            for part in name.split(","):
                f, n = failed_tests(Path(part))
                failed |= f
                run += n
        except (OSError, ET.ParseError) as exc:
            print(f"pass {i}: no readable JUnit file ({name}: {exc})")
            unreadable = True
            per_pass.append(set())
            continue
        print(f"pass {i}: {run} tests, {len(failed)} failed ({name})")
        per_pass.append(failed)
    every = set().union(*per_pass)
    always = set.intersection(*per_pass) if per_pass else set()
    flakes = sorted(every - always)
    print(f"flakes (failed in some passes, passed in others): {len(flakes)}")
    for t in flakes:
        where = ", ".join(str(i) for i, s in enumerate(per_pass, 1) if t in s)
        print(f"  {t}  (failed in pass {where})")
    print(f"failed in every pass: {len(always)}")
    for t in sorted(always):
        print(f"  {t}")
    print(f"tests that failed in any pass: {len(every)}")
    if unreadable:
        return 2
    return 1 if every else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
