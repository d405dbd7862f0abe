"""``rig console``: the drive's SCI console, interactive or scripted."""

from __future__ import annotations

import argparse
import contextlib
import sys
from collections.abc import Iterable, Iterator

from rig import cliargs
from rig.exit_status import EXIT_ENV, EXIT_FAIL, EXIT_OK, EXIT_USAGE

EPILOG = """\
interactive (a terminal on stdin): line editing and history (readline), TAB completes
command and parameter names; Ctrl-D ends. Scripted: --command LINE (repeatable) or lines on
stdin; each reply is printed as the drive wrote it.

exit status: 0 every reply OK; 1 an ERR reply (scripted: stops at the first one unless
--keep-going); 2 usage; 3 the port cannot be opened or the drive does not answer in time.
"""


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = cliargs.verb(
        sub, "console", help="talk to the drive's SCI console (serial port, pty or URL)",
        description="Client of the drive's SCI console (protocols/console.md): 115200 8N1 on "
        "a serial device, a pseudo-terminal (fw_host --pty-link) or a pyserial URL "
        "(rfc2217://host:port, socket://host:port).",
        epilog=EPILOG)
    where = p.add_mutually_exclusive_group()
    where.add_argument("--port", metavar="PORT|URL",
                       help="device, pty path or pyserial URL (this or --bench)")
    cliargs.add_shared(p, "bench", container=where,
                       help="take the console port from a bench description")
    p.add_argument("--command", "-c", action="append", default=[], metavar="LINE",
                   help="send this line (repeatable); without it lines come from stdin")
    cliargs.add_shared(p, "timeout", help="reply time-out, s (default: the bench's, else 2 s)")
    p.add_argument("--keep-going", action="store_true",
                   help="scripted: go on after an ERR reply")
    cliargs.command(p, cmd_console)


def _port(args: argparse.Namespace) -> tuple[str, float]:
    if args.port:
        return args.port, args.timeout or 2.0
    from rig.bench import description

    desc = description.load(args.bench)
    if not desc.console.port:
        raise description.BenchDescriptionError(
            f"{args.bench}: no console.port (a virtual bench's console is the pty of a "
            "running fw_host: use --port RUN/console.pty)")
    return desc.console.port, args.timeout or desc.console.timeout_s


def cmd_console(args: argparse.Namespace) -> int:
    from rig.bench.description import BenchDescriptionError
    from rig.drive.console import ConsoleClient, ConsoleLinkError

    if bool(args.port) == bool(args.bench):
        print("rig console: error: give the console as --port PORT|URL or --bench FILE "
              "(one of them)", file=sys.stderr)
        return EXIT_USAGE
    try:
        port, timeout = _port(args)
    except BenchDescriptionError as exc:
        print(f"rig console: {exc}", file=sys.stderr)
        return EXIT_USAGE
    client = ConsoleClient(port, timeout_s=timeout)
    try:
        client.open()
        if args.command:
            return _scripted(client, args.command, args.keep_going)
        if sys.stdin.isatty():
            return _interactive(client)
        return _scripted(client, (line.rstrip("\r\n") for line in sys.stdin), args.keep_going)
    except ConsoleLinkError as exc:
        print(f"rig console: {exc}", file=sys.stderr)
        return EXIT_ENV
    finally:
        client.close()


def _scripted(client: object, lines: Iterable[str], keep_going: bool) -> int:
    from rig.drive.console import ConsoleClient

    assert isinstance(client, ConsoleClient)
    status = EXIT_OK
    for line in lines:
        if not line.strip():
            continue
        try:
            reply = client.request(line)
        except UnicodeEncodeError:
            print(f"rig console: {line!r} is not ASCII", file=sys.stderr)
            return EXIT_USAGE
        print("\n".join(reply.lines(client.grammar.data_prefix)), flush=True)
        if not reply.ok:
            status = EXIT_FAIL
            if not keep_going:
                break
    return status


@contextlib.contextmanager
def _readline(words: list[str]) -> Iterator[None]:
    try:
        import readline
    except ImportError:  # no line editing on this Python
        yield
        return

    def complete(text: str, state: int) -> str | None:
        found = [w for w in words if w.startswith(text)]
        return found[state] if state < len(found) else None

    old = readline.get_completer()
    readline.set_completer(complete)
    readline.parse_and_bind("tab: complete")
    try:
        yield
    finally:
        readline.set_completer(old)


def _interactive(client: object) -> int:
    from rig.drive import params
    from rig.drive.console import ConsoleClient

    assert isinstance(client, ConsoleClient)
    g = client.grammar
    words = sorted({*g.commands, *params.table().by_name,
                    *(c for cmd in g.commands.values() for a in cmd.args for c in a.choices)})
    print(f"console {client.port} (protocol {g.version}); 'help' lists the drive's commands, "
          "Ctrl-D ends", file=sys.stderr)
    status = EXIT_OK
    with _readline(words):
        while True:
            try:
                line = input("> ")
            except EOFError:
                print(file=sys.stderr)
                return status
            except KeyboardInterrupt:
                print("^C", file=sys.stderr)
                continue
            if not line.strip():
                continue
            try:
                reply = client.request(line)
            except UnicodeEncodeError:
                print("only ASCII can be sent", file=sys.stderr)
                continue
            print("\n".join(reply.lines(g.data_prefix)), flush=True)
            if not reply.ok:
                status = EXIT_FAIL
