"""``rig drive``: run the drive of a bench from the command line (speed or q current, load
torque) for a while, then stop it safely.

The drive takes DRIVE_CMD every 10 ms while enabled (its command time-out faults it
otherwise), so the command stays in the foreground as the drive's CAN master; at the end,
on Ctrl-C or SIGTERM and on any failure it goes through the commissioning's safe stop
(drive disabled over CAN and the console, load zeroed over Modbus, read back)."""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

from rig import cliargs
from rig.exit_status import EXIT_ENV, EXIT_FAIL, EXIT_INTERRUPTED, EXIT_OK, EXIT_USAGE

PRINT_EVERY_S = 1.0


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = cliargs.verb(
        sub, "drive", help="run the drive (speed or q current, load torque) for a while",
        description="Enables the drive of a bench (a bench file: rig up writes one for the "
        "virtual bench) in speed control (--speed) or current control (--iq), sets the load "
        "machine's torque (--load), prints speed, currents and torque every second, and "
        "disables the drive and zeroes the load at the end (--for), on Ctrl-C or on a fault.",
        epilog="exit status: 0 ran and stopped; 1 the drive faulted or a command was not read "
        "back; 2 usage; 3 the bench cannot be reached; 130 interrupted (the drive stopped "
        "safely all the same).")
    cliargs.add_shared(p, "bench", required=True, help="bench description (file)")
    what = p.add_mutually_exclusive_group(required=True)
    what.add_argument("--speed", type=cliargs.number(float), metavar="RPM",
                      help="speed control at this reference, r/min")
    what.add_argument("--iq", type=cliargs.number(float), metavar="A",
                      help="current control: this q current, A (the drive's torque command)")
    p.add_argument("--load", type=cliargs.number(float), default=0.0, metavar="NM",
                   help="load machine torque, N·m (default 0: free shaft)")
    p.add_argument("--fw-mode", choices=("realtime", "conventional", "id_zero"),
                   default="realtime", help="MTPA / flux-weakening mode (default realtime)")
    p.add_argument("--for", dest="for_s", type=cliargs.number(float, minimum=0.0),
                   default=None, metavar="S", help="run this long, then stop (default: until "
                   "Ctrl-C)")
    p.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                   help="override a field of the bench description (repeatable)")
    cliargs.command(p, cmd_drive)


def cmd_drive(args: argparse.Namespace) -> int:
    from rig.bench import description
    from rig.commissioning.checked_drive import DriveError
    from rig.commissioning.session import BenchSession
    from rig.link.bus import LinkError
    from rig.link.clock import BenchTimeout
    from rig.loadbench.client import LoadBenchError
    from rig.supervisor import Terminated, terminate_as_exception

    try:
        desc = description.load(args.bench, args.set)
    except description.BenchDescriptionError as exc:
        print(f"rig drive: {exc}", file=sys.stderr)
        return EXIT_USAGE
    if desc.virtual is not None:
        print(f"rig drive: {args.bench} starts a virtual bench of its own; bring one up with "
              "`rig up` and give its bench file", file=sys.stderr)
        return EXIT_USAGE
    import tempfile

    status = EXIT_OK
    with tempfile.TemporaryDirectory(prefix="hil-drive-") as tmp, terminate_as_exception():
        s = BenchSession(desc, Path(tmp))
        try:
            s.start()
            s.open_console()
            lb = s.open_load()
            cfg = s.config
            s.drive.require_idle("rig drive")
            lb.torque_mode(0.0)
            s.drive.set_limits(cfg.i_max_a, cfg.speed_max_rpm, cfg.accel_rpm_s)
            if args.speed is not None:
                s.drive.enable(ctrl_mode="speed", fw_mode=args.fw_mode, speed_ref=0.0,
                               timeout_s=cfg.start_timeout_s)
                s.drive.command(speed_ref=args.speed)
            else:
                s.drive.enable(ctrl_mode="current", fw_mode=args.fw_mode, iq_ref=0.0,
                               timeout_s=cfg.start_timeout_s)
                s.drive.command(iq_ref=args.iq)
            lb.set_torque(args.load)
            _run(s, args.for_s)
        except (KeyboardInterrupt, Terminated):
            status = EXIT_INTERRUPTED
        except (DriveError, BenchTimeout, LoadBenchError) as exc:
            print(f"rig drive: {exc}", file=sys.stderr)
            status = EXIT_FAIL
        except (LinkError, OSError, RuntimeError) as exc:
            print(f"rig drive: {exc}", file=sys.stderr)
            status = EXIT_ENV
        finally:
            if s.started:
                for note in s.safe_stop():
                    print(f"rig drive: safe stop: {note}", file=sys.stderr)
            s.close()
    return status


def _run(s, for_s: float | None) -> None:  # type: ignore[no-untyped-def]
    """Holds the command (the clock sends DRIVE_CMD every 10 ms), a line every second."""
    from rig.commissioning.telemetry import Window

    t0 = time.monotonic()
    print("     t (s)  state  speed est (r/min)  speed (r/min)  id (A)  iq (A)  "
          "shaft torque (N·m)", flush=True)
    while for_s is None or time.monotonic() - t0 < for_s:
        step = PRINT_EVERY_S if for_s is None else min(
            PRINT_EVERY_S, max(0.0, for_s - (time.monotonic() - t0)))
        with Window(s.link) as w:
            s.clock.advance(step)
        s.drive.check_no_fault("rig drive")
        m = s.load.measure()
        cells = [w.mean("TLM_POS", "speed_hat"), m.speed_rpm, w.mean("TLM_CUR", "id"),
                 w.mean("TLM_CUR", "iq"), m.shaft_torque]
        text = "  ".join("     n/a" if math.isnan(v) else f"{v:8.2f}" for v in cells)
        print(f"{time.monotonic() - t0:10.1f}  {s.drive.state:5s}  {text}", flush=True)
