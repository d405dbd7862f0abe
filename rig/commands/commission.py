"""``rig commission``: the commissioning scripts on a virtual or a real bench."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from rig import cliargs
from rig.exit_status import EXIT_ENV, EXIT_FAIL, EXIT_INTERRUPTED, EXIT_OK, EXIT_USAGE

EPILOG = """\
steps (in the order 'all' runs them; each starts and ends with the drive disabled and the
load off, so any step runs alone):
  connectivity  CAN heartbeat and parameter read, console ping/version, Modbus read/watchdog
  polarity      start-up polarity detection + torque-sign check, locked rotor (not in 'all':
                'standstill' includes it)
  standstill    polarity, Ld/Lq from the slope estimator, rs from locked-rotor current steps
  start         sensorless start at low speed on a free shaft
  flux          λm at speeds held by the load machine (±iq, id = 0)
  xsat          cross-saturation: the saliency axes against the flux angle at a held speed,
                q currents of both signs; writes xsat_ldq_per_a
  sweep         speed control at several speeds with load steps

output: RUN/commissioning.md (report), RUN/commissioning.json, RUN/bus.log (recording), and
on a virtual bench RUN/logs/ and the console pty. Any failure, time-out, lost link or Ctrl-C
disables the drive (DRIVE_CMD enable 0 and console 'disable') and zeroes the load first.

channel: on the virtual bench a session that names none (--set can.channel=NAME) gets a
unixcan channel of its own (commission-<pid>, in the report); the channel is held for the
session and must be quiet before anything starts (a node sending there, or another run of
the rig on it, is refused: exit 3). A real bench uses its description's channel.

exit status: 0 every step passed; 1 a check failed or a step stopped; 2 usage; 3 the
channel is in use (foreign traffic, another run of the rig): nothing was started; 130
interrupted.
"""


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = cliargs.verb(
        sub, "commission", help="commissioning scripts (virtual or real bench)",
        description="Run commissioning steps against the bench a description names "
        "(rig/benches/virtual.toml starts plant_rt, fw_host and the Modbus load bench in "
        "lockstep; a real bench runs on the wall clock).",
        epilog=EPILOG)
    p.add_argument("step", nargs="+", metavar="STEP",
                   help="a step (listed below) or 'all'; several allowed")
    cliargs.add_shared(p, "bench", required=True,
                       help="bench description (a file, or a shipped name: virtual)")
    p.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                   help="override a field of the bench description (repeatable)")
    cliargs.add_shared(p, "out", type=Path,
                       help="run folder (default: ./out/commission-NAME-TIME)")
    cliargs.add_shared(p, "quiet", help="no progress lines")
    p.add_argument("--save-params", type=Path, default=None, metavar="FILE",
                   help="after a passing run, write the drive parameters the steps identified "
                   "(rs_ohm, ld_h, lq_h, lambda_m_wb, xsat_ldq_per_a) or wrote to the drive "
                   "as a TOML [firmware] table, whole or not at all; rig/commissioned/"
                   "PROFILE.toml is what scenario runs on that virtual bench use. FILE is "
                   "checked before the run: neither it nor a folder on the way to it may be a "
                   "symbolic link, and an existing "
                   "FILE is replaced only if --save-params wrote it")
    cliargs.command(p, cmd_commission)


def cmd_commission(args: argparse.Namespace) -> int:
    from rig.bench import description
    from rig.commissioning import commission

    try:
        desc = description.load(args.bench, args.set)
        steps = commission.expand(args.step)
    except (description.BenchDescriptionError, ValueError) as exc:
        print(f"rig commission: {exc}", file=sys.stderr)
        return EXIT_USAGE
    if args.save_params is not None:
        problem = _save_target_problem(args.save_params)
        if problem is not None:
            print(f"rig commission: --save-params: {problem}", file=sys.stderr)
            return EXIT_USAGE
    out = args.out or commission.default_run_dir(desc)

    def say(msg: str) -> None:
        if not args.quiet:
            print(f"rig commission: {msg}", file=sys.stderr, flush=True)

    try:
        run = commission.commission(desc, steps, out, say)
    except KeyboardInterrupt:
        print(f"rig commission: interrupted; drive disabled and load zeroed; report in {out}",
              file=sys.stderr)
        return EXIT_INTERRUPTED
    ids = run.data.get("identified", {})
    for key in ("rs_ohm", "ld_h", "lq_h", "lambda_m_wb"):
        if key in ids:
            print(f"{key} = {ids[key]:.6g}")
    if run.data.get("error"):
        print(f"rig commission: {run.data['error']}", file=sys.stderr)
    for s in run.steps:
        if s.error:
            print(f"rig commission: step {s.step} stopped: {s.error}", file=sys.stderr)
    verdict = "PASSED" if run.passed else "FAILED"
    print(f"commissioning {verdict}: {run.report_path}")
    if run.data.get("refused"):
        return EXIT_ENV
    if args.save_params is not None:
        if not _save_params(args.save_params, run.data, desc):
            return EXIT_FAIL
    return EXIT_OK if run.passed else EXIT_FAIL


def _save_target_problem(path: Path) -> str | None:
    """Why --save-params cannot write ``path`` (checked before the run, so a long run is not
    lost to it at the end), or None."""
    from rig.drive import commissioned

    if path.is_symlink():
        return f"{path} is a symbolic link; refused (nothing is written through a link)"
    link = _link_above(path)
    if link is not None:
        return (f"{path} lies in {link}, which is a symbolic link; refused (nothing is "
                "written through a link: name the folder it points to)")
    if path.exists():
        if not path.is_file():
            return f"{path} is not a regular file"
        if not commissioned.is_saved_file(path):
            return (f"{path} exists and was not written by --save-params; refused (remove it "
                    "or choose another FILE)")
    if not path.parent.is_dir():
        return f"{path.parent} is not a folder"
    return None


def _link_above(path: Path) -> Path | None:
    """The first folder on the way to ``path`` (as given, from the current folder, whose own
    path holds no link) that is a symbolic link, or None."""
    import os

    folder = Path(os.path.abspath(path)).parent
    for above in (*reversed(folder.parents), folder):
        if above.is_symlink():
            return above
    return None


def _save_params(path: Path, data: dict, desc) -> bool:  # type: ignore[no-untyped-def,type-arg]
    """Writes the drive parameters the run identified or wrote to the drive, whole or not at
    all; False (with the reason) when it cannot."""
    from rig import outputs
    from rig.drive import commissioned

    if not data.get("passed"):
        print(f"rig commission: --save-params: the run did not pass; {path} not written",
              file=sys.stderr)
        return False
    try:
        values = commissioned.values_to_save(data.get("identified") or {},
                                                   data.get("written") or {})
    except commissioned.CommissionedError as exc:
        print(f"rig commission: --save-params: {exc}; {path} not written", file=sys.stderr)
        return False
    if not values:
        print(f"rig commission: --save-params: no step identified or wrote a drive parameter; "
              f"{path} not written", file=sys.stderr)
        return False
    problem = _save_target_problem(path)  # (again: the run took a while)
    if problem is not None:
        print(f"rig commission: --save-params: {problem}", file=sys.stderr)
        return False
    profile = desc.virtual.profile if desc.virtual is not None else desc.name
    try:
        outputs.write_text(path, commissioned.render(values, profile,
                                                          ["rig", *sys.argv[1:]]))
    except OSError as exc:
        print(f"rig commission: --save-params: {exc}", file=sys.stderr)
        return False
    print(f"drive parameters ({', '.join(sorted(values))}) -> {path}")
    return True
