"""``rig clean``: list old runs under the output root and remove them when told to."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from rig import cliargs

EPILOG = """\
which runs: rig run / rig sweep without --out write a new folder NAME-YYYYmmdd-HHMMSS under
$HIL_OUT (else ./out) each time; those pile up. rig clean lists every run folder under the
root and marks for removal the auto-named ones beyond the newest --keep-last (default 5),
or with --older-than only those older than that. --all also takes folders named with --out
(./hil main's out/paper, ./hil test's out/ci/...). A folder holding a file named KEEP
(`touch DIR/KEEP`), or lying in a folder that holds one (up to the root), is never removed.
Nothing is removed without --yes.

exit status: 0 done (or nothing to do); 2 usage; 3 the root is not a folder.
"""

# a notice after rig run when the default root holds more than this
NOTICE_BYTES = 2_000_000_000
NOTICE_RUNS = 20


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = cliargs.verb(
        sub, "clean", help="list old run folders under the output root; remove them with --yes",
        description="List the run folders under the output root (size, age, verdict, whether "
        "they still hold full-rate traces) and remove the old auto-named ones.",
        epilog=EPILOG,
    )
    p.add_argument("root", nargs="?", type=Path, default=None, metavar="ROOT",
                   help="the output root (default: $HIL_OUT, else ./out)")
    p.add_argument("--keep-last", type=int, default=5, metavar="N",
                   help="never remove the newest N candidate runs (default 5)")
    p.add_argument("--older-than", type=float, default=None, metavar="DAYS",
                   help="remove only runs older than DAYS")
    p.add_argument("--all", action="store_true",
                   help="also runs in folders named with --out (out/paper, out/ci/...)")
    p.add_argument("--yes", action="store_true", help="remove them (default: only list)")
    p.set_defaults(func=cmd_clean)


def _mb(n: int) -> str:
    return f"{n / 1e6:,.1f} MB"


def cmd_clean(args: argparse.Namespace) -> int:
    from rig import outputs

    root: Path = args.root or outputs.default_root()
    if args.keep_last < 0 or (args.older_than is not None and args.older_than < 0):
        print("rig clean: --keep-last and --older-than take numbers >= 0", file=sys.stderr)
        return 2
    if not root.exists():
        print(f"rig clean: {root} does not exist: nothing to clean")
        return 0
    if not root.is_dir():
        print(f"rig clean: {root} is not a folder", file=sys.stderr)
        return 3
    runs = list(outputs.find_runs(root))
    chosen = outputs.select(runs, keep_last=args.keep_last, older_than_days=args.older_than,
                            include_named=args.all)
    gone = {r.path for r in chosen}
    print(f"{'':2}{'RUN':<48} {'KIND':<8} {'WHEN':<16} {'SIZE':>12}  NOTE")
    for r in sorted(runs, key=lambda r: r.when):
        mark = "x " if r.path in gone else "  "
        verdict = {True: "pass", False: "FAIL", None: ""}[r.passed]
        notes = [verdict] if verdict else []
        if r.full_rate:
            notes.append("full-rate data")
        if r.keep:
            notes.append("KEEP")
        elif not r.auto_named:
            notes.append("named (--all)")
        rel = r.path.relative_to(root) if root in r.path.parents else r.path
        print(f"{mark}{rel!s:<48} {r.kind:<8} {r.when:%Y-%m-%d %H:%M} {_mb(r.bytes):>12}  "
              f"{', '.join(notes)}")
    total = sum(r.bytes for r in runs)
    freed = sum(r.bytes for r in chosen)
    print(f"{len(runs)} runs, {_mb(total)} in {root}; {len(chosen)} marked x ({_mb(freed)})")
    if not chosen:
        return 0
    if not args.yes:
        print("nothing removed: add --yes to remove the runs marked x")
        return 0
    for r in chosen:
        outputs.remove(r, root)
    print(f"removed {len(chosen)} runs ({_mb(freed)})")
    return 0


def notice(root: Path) -> str | None:
    """A one-line hint when the output root has grown (after rig run), else None."""
    from rig import outputs

    runs = [r for r in outputs.find_runs(root) if r.auto_named]
    size = sum(r.bytes for r in runs)
    if size < NOTICE_BYTES and len(runs) <= NOTICE_RUNS:
        return None
    return (f"rig: {root} holds {len(runs)} runs named by time ({_mb(size)}); `rig clean` lists "
            "them and removes the old ones with --yes")
