"""``rig watch``: a live Rerun view of a bench that is running (the virtual bench `rig up`
brings up, or a real one), attached to its bus as a listener.

It sends nothing, so it can come and go while the bench runs: the drive never knows. It shows
what a run's ``--live`` shows, from the same frames: the drive's telemetry (TLM_*, 1 kHz) and,
on the virtual bench, the plant's truth (BENCH_TRUTH) beside it."""

from __future__ import annotations

import argparse
import contextlib
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

from rig import cliargs
from rig.exit_status import EXIT_ENV, EXIT_OK, EXIT_USAGE

if TYPE_CHECKING:
    import rerun as rr

    from rig.link.bus import BusLink

FLUSH_EVERY_S = 0.25  # the viewer gets what was heard this often
QUIET_WARNING_S = 5.0  # nothing heard this long: say so (once), and keep listening


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = cliargs.verb(
        sub, "watch", help="a live Rerun view of a running bench (attach, Ctrl-C detaches)",
        description="Listens to a running bench's bus (a bench file: rig up writes one for "
        "the virtual bench) and streams the drive's telemetry, and the plant's truth where "
        "the bench sends it, to a Rerun viewer until Ctrl-C or --for. It sends nothing: "
        "start and stop it while the bench runs.",
        epilog="exit status: 0 detached (Ctrl-C, SIGTERM, --for); 2 usage; 3 the bus or the "
        "viewer cannot be opened.")
    cliargs.add_shared(p, "bench", help="take the bus from a bench description")
    cliargs.add_shared(p, "bus", choices=cliargs.BUS_TRANSPORTS,
                       help="transport (default: the bench's, else $HIL_BUS, else auto)")
    cliargs.add_shared(p, "channel", env="HIL_CHANNEL",
                       help="bus channel (default: the bench's, else $HIL_CHANNEL, else vcan0)")
    p.add_argument("--web", action="store_true",
                   help="stream to the Rerun web viewer (its address is printed; it stops "
                   "with the watch); the default without a display")
    p.add_argument("--web-port", type=cliargs.port, default=None, metavar="PORT",
                   help="with --web: the web viewer's HTTP port (default 9090)")
    p.add_argument("--grpc-port", type=cliargs.port, default=None, metavar="PORT",
                   help="the viewer's gRPC port (default 9876)")
    p.add_argument("--save", type=Path, default=None, metavar="FILE.rrd",
                   help="write the stream to this recording instead of a viewer (refused if "
                   "FILE exists; open it later with `rerun FILE`)")
    p.add_argument("--for", dest="for_s", type=cliargs.number(float, minimum=0.0),
                   default=None, metavar="S", help="detach by itself after S seconds")
    cliargs.command(p, cmd_watch)


def cmd_watch(args: argparse.Namespace) -> int:
    from rig.bench import description
    from rig.link.bus import BusLink, LinkError
    from rig.results import webview

    bus, channel = args.bus, args.channel
    if args.bench:
        try:
            desc = description.load(args.bench)
        except description.BenchDescriptionError as exc:
            print(f"rig watch: {exc}", file=sys.stderr)
            return EXIT_USAGE
        if desc.virtual is not None and desc.virtual.programs:
            print(f"rig watch: {args.bench} starts a virtual bench of its own; bring one up "
                  "with `rig up` and give its bench file", file=sys.stderr)
            return EXIT_USAGE
        bus, channel = bus or desc.can.transport, channel or desc.can.channel
    if args.save is not None and (args.web or args.web_port or args.grpc_port):
        print("rig watch: --save writes a file; --web, --web-port and --grpc-port are for a "
              "viewer", file=sys.stderr)
        return EXIT_USAGE
    if args.save is not None and (args.save.exists() or args.save.is_symlink()):
        print(f"rig watch: {args.save} exists; refused (remove it or choose another FILE)",
              file=sys.stderr)
        return EXIT_USAGE
    try:
        link = BusLink.open(bus, channel)
    except (LinkError, ValueError) as exc:
        print(f"rig watch: {exc}", file=sys.stderr)
        return EXIT_ENV
    try:
        with contextlib.ExitStack() as viewer:
            try:
                stream = _stream(args, f"{link.where} (watch)", viewer)
            except webview.WebViewerError as exc:
                print(f"rig watch: {exc}", file=sys.stderr)
                return EXIT_ENV
            return _watch(link, stream, args.for_s)
    finally:
        link.close()


def _stream(args: argparse.Namespace, title: str,
            viewer: contextlib.ExitStack) -> rr.RecordingStream:
    """Where the view goes: the file of --save, a native window, or the web viewer (the
    default without a display), whose server ``viewer`` stops."""
    import rerun as rr  # (for --save: the others import it through recording)

    from rig.results import recording, webview

    if args.save is not None:
        rec = rr.RecordingStream(recording.APP_ID + "_live")
        rec.save(args.save)
        return rec
    grpc = args.grpc_port or webview.DEFAULT_GRPC_PORT
    if not args.web and not webview.has_display():
        print(f"rig watch: {webview.NO_DISPLAY}: the live view goes to the web viewer",
              file=sys.stderr)
    elif not args.web:
        return recording.spawn_live(title, webview.start_native(grpc_port=grpc))
    server = viewer.enter_context(webview.start(
        web_port=args.web_port or webview.DEFAULT_WEB_PORT, grpc_port=grpc))
    print(f"rig watch: the live view in the web viewer at {server.url()} (Ctrl-C detaches)",
          file=sys.stderr, flush=True)
    return recording.spawn_live(title, server.grpc_url)


def _watch(link: BusLink, stream: rr.RecordingStream, for_s: float | None) -> int:
    """Streams what ``link`` hears until Ctrl-C, SIGTERM or ``for_s``; 0 (detached)."""
    from rig.results import recording
    from rig.run.live import LiveFeed
    from rig.run.monitor import Monitor
    from rig.supervisor import Terminated, terminate_as_exception

    view = recording.LiveView(stream)

    def truth_period() -> int | None:
        truth = link.latest.get("BENCH_TRUTH")
        return int(truth["period"]) if truth else None

    feed = LiveFeed(view, link, Monitor(link), truth_period)
    print(f"rig watch: listening on {link.where}", file=sys.stderr, flush=True)
    t0 = last_flush = time.monotonic()
    warned = False
    try:
        with terminate_as_exception():
            while for_s is None or time.monotonic() - t0 < for_s:
                link.pump(0.05)
                now = time.monotonic()
                if now - last_flush >= FLUSH_EVERY_S:
                    feed.flush()
                    last_flush = now
                if not warned and link.rx == 0 and now - t0 >= QUIET_WARNING_S:
                    print(f"rig watch: nothing heard on {link.where} in {QUIET_WARNING_S:g} s "
                          "(is the bench up, on this channel?); still listening",
                          file=sys.stderr, flush=True)
                    warned = True
    except (KeyboardInterrupt, Terminated):
        pass
    finally:
        feed.flush()
        feed.close()
    rows = view.rows.get("position", 0)
    print(f"rig watch: detached ({link.rx} frames heard, {rows} position samples shown)",
          file=sys.stderr, flush=True)
    return EXIT_OK
