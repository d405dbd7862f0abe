"""``rig export``: a run's full-rate data as ASAM MDF4 and as a CAN log."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from rig import cliargs

EPILOG = """\
--mf4 [FILE]        the capture (every PWM period: the plant's truth, the firmware's trace and
                    the rig's derived columns) as ASAM MDF 4.10, channels named MESSAGE.signal
                    with units, comments and value tables from the DBC, and the run's frames
                    as a CAN bus-logging group (default FILE: DIR/<scenario>.mf4; a folder:
                    FOLDER/<scenario>.mf4); asammdf's GUI, CANape, MDF viewers
--can-log FILE      every frame of the run: FILE.blf (Vector BLF), FILE.asc (Vector ASCII)
                    or FILE.log (candump -L); channel 0 the plant's (VIO_ADC, VIO_PWM, its
                    truth), 1 the firmware's FW_TRACE, 2 the rig's (DRIVE_*, BENCH_*, TLM_*);
                    SavvyCAN, CANalyzer, python-can (can.player), cantools, can-utils

Both need the full-rate data (DIR/*.trace and DIR/capture/): a run that did not pass keeps
it, a passing run only with `rig run --keep-all`.

exit status: 0 written; 2 usage, or DIR lacks the full-rate data, or it is damaged (a trace
cut short, a file that is not the rig's), or FILE is not a file name of its kind; 3 a file
cannot be written. Nothing is left behind when a file cannot be written.
"""


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = cliargs.verb(
        sub, "export", help="write a run's full-rate data as ASAM MDF4 (--mf4) or a CAN log "
        "(--can-log FILE.blf|.asc|.log)",
        description="Write a run's full-rate capture as ASAM MDF4 (asammdf) and its traced "
        "frames as a CAN log (python-can), for the tools of the field.",
        epilog=EPILOG,
    )
    p.add_argument("run_dir", type=Path, metavar="DIR", help="a scenario's run folder")
    p.add_argument("--mf4", nargs="?", type=Path, const=True, default=None, metavar="FILE",
                   help="write the capture as MDF 4.10 (default FILE: DIR/<scenario>.mf4)")
    p.add_argument("--can-log", type=Path, default=None, metavar="FILE",
                   help="write the traced frames to FILE (.blf, .asc or .log)")
    cliargs.command(p, cmd_export)


def cmd_export(args: argparse.Namespace) -> int:
    from rig.data import export

    run_dir: Path = args.run_dir
    if args.mf4 is None and args.can_log is None:
        print("rig export: say what to write: --mf4 [FILE] and/or --can-log FILE",
              file=sys.stderr)
        return 2
    if not run_dir.is_dir():
        print(f"rig export: {run_dir} is not a folder", file=sys.stderr)
        return 2
    try:
        if args.mf4 is not None:
            dest = run_dir if args.mf4 is True else args.mf4
            if dest.is_dir():  # a folder: the file in it, named after the scenario
                dest = dest / f"{export.default_name(run_dir)}.mf4"
            info = export.write_mf4(run_dir, dest)
            print(f"rig export: {info['channels']} channels in {info['groups']} groups, "
                  f"{info['samples']} samples each, and {info['frames']} frames -> {dest} "
                  f"({info['bytes'] / 1e6:.1f} MB)")
        if args.can_log is not None:
            info = export.write_can_log(run_dir, args.can_log)
            print(f"rig export: {info['frames']} frames -> {args.can_log} "
                  f"({info['bytes'] / 1e6:.1f} MB), {info['kind']} (not a live capture: "
                  "rig run --can-log" + ("" if info["kind_in_file"] else
                                         "; the candump format cannot say so in the file")
                  + ")")
    except export.ExportError as exc:
        print(f"rig export: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"rig export: cannot write: {exc}", file=sys.stderr)
        return 3
    return 0
