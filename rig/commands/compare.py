"""``rig compare A B``: two results side by side, judged against the seed spread."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from rig import cliargs

EPILOG = """\
A and B: a run folder, a suite folder, a `rig baseline record` folder (seed-N/ inside: the
mean over its seeds), a baseline file, or baseline:SUITE (the committed one). Each criterion
is unchanged (within the seed spread), improved, regressed, changed (beyond the spread, no
better side), unknown (no spread known), added or removed; with its change in % and in band
half-widths and the chance of a difference that large, most significant first. A baseline
side is narrowed to the other side's scenario runs.

--exact asks more: every criterion of B is in A with the very same value (each seed's too)
and outcome; A may hold more runs (the bus's runs against the gate's in process: the same
computation, so any difference is a defect).

exit status: 0 nothing regressed or changed (--exact: B identical to A); 1 something did
(--exact: a criterion of B differs from A's or is not in A); 2 usage, a side that cannot be
read, or sides that are not comparable (one evaluated nothing, or no scenario run in
common); 3 --out cannot be written.
"""


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = cliargs.verb(
        sub, "compare", help="two runs, suites or baselines side by side, against the seed spread",
        description="Per scenario run and criterion: A's value, B's, the difference and "
        "whether it is beyond the spread the plant's noise seeds give (the baseline's band). "
        "What a reviewer reads before a firmware change is merged.",
        epilog=EPILOG)
    p.add_argument("a", metavar="A")
    p.add_argument("b", metavar="B")
    p.add_argument("--all", action="store_true",
                   help="list every criterion, not only those that moved")
    p.add_argument("--exact", action="store_true",
                   help="B must equal A to the bit on every criterion B holds (exit 1 "
                   "otherwise)")
    cliargs.add_shared(p, "out", type=Path,
                       help="also write DIR/compare.md, compare.json and a plot per moved "
                       "metric")
    cliargs.command(p, cmd_compare)


def cmd_compare(args: argparse.Namespace) -> int:
    import json

    from rig.regression import compare

    try:
        a, b = compare.load_side(args.a), compare.load_side(args.b)
        rows = compare.compare(a, b)
    except compare.CompareError as exc:
        print(f"rig compare: {exc}", file=sys.stderr)
        return 2
    head = f"rig compare: A = {a.label}, B = {b.label}"
    table = compare.markdown(rows, only_changed=not args.all)
    summary = compare.summary_line(rows)
    print(f"{head}\n{summary}\n\n{table}")
    if args.out is not None:
        from rig import outputs

        try:
            outputs.prepare(args.out)
            pngs = compare.plots(rows, args.out, "A", "B")
            md = [f"# {head}", "", summary, "", table, ""]
            md += [f"![{p.stem}]({p.name})" for p in pngs]
            outputs.write_text(args.out / "compare.md", "\n".join(md) + "\n")
            outputs.write_text(args.out / "compare.json",
                              json.dumps({"a": a.label, "b": b.label,
                                          "rows": compare.to_json(rows)}, indent=1))
        except (OSError, outputs.OutputError) as exc:
            print(f"rig compare: --out {args.out}: {getattr(exc, 'strerror', None) or exc}",
                  file=sys.stderr)
            return 3
        print(f"\n-> {args.out}/compare.md ({len(pngs)} plots)", file=sys.stderr)
    if args.exact:
        differ = compare.not_identical_in_b(rows)
        for r in differ[:20]:
            a = "absent" if r.a is None else f"{r.a.value} ({r.a.outcome})"
            b = "absent" if r.b is None else f"{r.b.value} ({r.b.outcome})"
            print(f"rig compare: --exact: {r.key[0]} {r.key[1]}: A {a}, B {b}",
                  file=sys.stderr)
        in_b = sum(1 for r in rows if r.b is not None)
        print(f"rig compare: --exact: {in_b - len(differ)} of {in_b} criteria of B identical "
              "to A's", file=sys.stderr)
        return 1 if differ else 0
    c = compare.counts(rows)
    return 1 if c.get("regressed") or c.get("changed") else 0
