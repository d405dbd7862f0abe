"""Every command line the README quotes works as written: the README is the source, so a
command added to it is tested without touching this file.

- In ``sh`` blocks: ``rig`` commands are parsed by the rig's own parser (options, choices,
  values; ``rig vm -- CMD`` and the command inside); ``./hil`` commands must name one of
  ``./hil``'s commands; ``cantools monitor`` and ``python -m can.logger`` are parsed by the
  tools' own parsers. The cheap ones run, in the README's order, in a scratch folder (``rig
  list``, ``rig run smoke --bus inproc``, a kept run and its export, ``rig clean``, the
  python-can logger and the cantools monitor on a pseudo-terminal, both on unixcan).
- In the prose: a command mentioned inline (`` `rig run --keep-all` ``) must name a command
  that exists and only options that command takes.

Only ``ip link`` (the operating system's, for a real CAN controller) is not checked.
"""

from __future__ import annotations

import argparse
import os
import re
import select
import shlex
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import pytest
from waits import EVENT_S, wait_until

from rig import cli, cliargs
from rig.bus import unixcan

ROOT = Path(__file__).resolve().parents[3]
README = ROOT / "README.md"
NOT_OURS = ("ip",)  # the OS's tools: shown for the lab, run by whoever owns the controller
ELLIPSIS = {"...", "…"}


@dataclass(frozen=True)
class Line:
    argv: tuple[str, ...]
    line: int
    inline: bool

    @property
    def id(self) -> str:
        return f"L{self.line}:{' '.join(self.argv)[:60]}"


def _split(text: str) -> list[str]:
    lexer = shlex.shlex(text, posix=True, punctuation_chars=False)
    lexer.whitespace_split = True
    lexer.commenters = "#"
    return list(lexer)


def readme_lines() -> list[Line]:
    text = README.read_text()
    out: list[Line] = []
    for m in re.finditer(r"```(\w*)\n(.*?)```", text, re.S):
        if m.group(1) != "sh":
            continue
        first = text.count("\n", 0, m.start(2)) + 1
        pending, start = "", 0
        for k, raw in enumerate(m.group(2).splitlines()):
            if not pending:
                start = first + k
            if raw.rstrip().endswith("\\"):
                pending += raw.rstrip()[:-1] + " "
                continue
            argv = _split(pending + raw)
            pending = ""
            if argv:
                out.append(Line(tuple(argv), start, inline=False))
    prose = re.sub(r"```.*?```", lambda m: "\n" * m.group(0).count("\n"), text, flags=re.S)
    for m in re.finditer(r"`([^`\n]+)`", prose):
        span = m.group(1)
        if re.match(r"(\.venv/bin/)?rig(\s|$)|\./hil\s", span):
            out.append(Line(tuple(a for a in _split(span) if a not in ELLIPSIS),
                            text.count("\n", 0, m.start()) + 1, inline=True))
    return out


LINES = readme_lines()


def test_the_readme_quotes_the_commands_this_test_knows() -> None:
    programs = {ln.argv[0] for ln in LINES}
    assert programs <= {"./hil", ".venv/bin/rig", "rig", "python", "cantools", *NOT_OURS}, (
        programs)
    assert sum(not ln.inline for ln in LINES) >= 25  # the sh blocks' commands, continuation
    assert any(ln.argv[:3] == ("cantools", "monitor", "-i") for ln in LINES)  # joined


def _rig_words(argv: tuple[str, ...]) -> list[str]:
    assert argv[0] in ("rig", ".venv/bin/rig"), argv
    return list(argv[1:])


def _hil_commands() -> set[str]:
    r = subprocess.run([str(ROOT / "hil"), "no-such-command"], capture_output=True,
                       text=True, check=False, timeout=30)
    usage = r.stderr.strip().splitlines()[-1]
    assert r.returncode == 2 and usage.startswith("usage: ./hil "), r.stderr
    return {part.split()[0] for part in usage.removeprefix("usage: ./hil ").split("|")}


def _leaf(words: list[str]) -> argparse.ArgumentParser:
    """The parser of the command the words name (rig bus status -> its parser)."""
    parser: argparse.ArgumentParser = cli.build_parser()
    for w in words:
        subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
        if not subs or w.startswith("-") or w not in subs[0].choices:
            break
        parser = subs[0].choices[w]
    return parser


def check_rig(words: list[str], inline: bool) -> None:
    if not inline:
        ns = cliargs.finish(cli.build_parser().parse_args(words))  # SystemExit on an error
        if words[0] == "vm":  # and the command it runs in the VM
            inner = [w for w in ns.command if w != "--"]
            if inner and inner[0] in ("rig", ".venv/bin/rig"):
                check_rig(inner[1:], inline=False)
        return
    # a mention: the command exists and takes the options named
    verbs = [w for w in words if not w.startswith("-")]
    leaf = _leaf(words)
    assert leaf.prog.split()[1:] == verbs[: len(leaf.prog.split()) - 1], (words, leaf.prog)
    known = {s for a in leaf._actions for s in a.option_strings}
    known |= {s for o in cliargs.SHARED.values() for s in o.flags} if leaf.get_default(
        cliargs.SHARED_KEY) else set()
    for w in words:
        if w == "--":
            break
        if w.startswith("--"):
            assert w.split("=", 1)[0] in known, f"{' '.join(words)}: {w} is not an option " \
                                                f"of {leaf.prog}"


def check_external(argv: tuple[str, ...]) -> None:
    if argv[0] == "cantools":
        import cantools.subparsers.monitor as monitor

        parser = argparse.ArgumentParser(prog="cantools")
        sub = parser.add_subparsers(dest="subcommand", required=True)
        monitor.add_subparser(sub)
        args = parser.parse_args(argv[1:])
        assert (ROOT / args.database).is_file(), args.database
        return
    assert argv[:3] == ("python", "-m", "can.logger"), argv
    from can.logger import _parse_logger_args

    results, extra = _parse_logger_args(list(argv[3:]))
    assert results.interface == "unixcan" and not extra


@pytest.mark.parametrize("line", LINES, ids=[ln.id for ln in LINES])
def test_readme_command_parses(line: Line) -> None:
    argv = line.argv
    if argv[0] in NOT_OURS:
        pytest.skip(f"{argv[0]}: the operating system's command")
    if argv[0] == "./hil":
        assert argv[1] in _hil_commands(), f"README line {line.line}: ./hil {argv[1]}"
    elif argv[0] in ("cantools", "python"):
        check_external(argv)
    else:
        check_rig(_rig_words(argv), line.inline)


# -- the cheap ones run, in the README's order --------------------------------------------

CHEAP = (
    re.compile(r"^rig list$"),
    re.compile(r"^rig run smoke --bus inproc$"),
    re.compile(r"^rig run smoke --keep-all --out \S+$"),
    re.compile(r"^rig export \S+ --mf4 --can-log \S+$"),
    re.compile(r"^rig clean$"),
    re.compile(r"^python -m can\.logger "),
    re.compile(r"^cantools monitor "),
)


def _cheap() -> list[Line]:
    out = []
    for ln in LINES:
        if ln.inline:
            continue
        text = " ".join(ln.argv).removeprefix(".venv/bin/")
        if any(p.search(text) for p in CHEAP):
            out.append(ln)
    return out


def test_the_cheap_readme_commands_run_as_written(tmp_path: Path) -> None:
    cheap = _cheap()
    assert len(cheap) == len(CHEAP), [ln.id for ln in cheap]  # each pattern still quoted
    (tmp_path / "protocols").symlink_to(ROOT / "protocols")
    env = {k: v for k, v in os.environ.items() if k not in ("HIL_BUS", "HIL_OUT")}
    env["HIL_CHANNEL"] = f"readme-{os.getpid()}"  # this test's own bus channel
    for ln in cheap:
        argv = list(ln.argv)
        if argv[0] in ("rig", ".venv/bin/rig"):
            cmd = [sys.executable, "-m", "rig", *argv[1:]]
        elif argv[0] == "python":
            cmd = [sys.executable, *argv[1:]]
        else:
            cmd = [sys.executable, "-m", "cantools", *argv[1:]]
        if argv[0] == "cantools":
            screen = _on_a_terminal(cmd, tmp_path, env)
            # decoded with the DBC, its value table included (state 2)
            assert "DRIVE_STATUS(" in screen and "state: POLARITY" in screen, screen[-2000:]
            continue
        if argv[0] == "python":
            out = _until_interrupted(cmd, tmp_path, env)
            assert re.search(r"ID:\s+0*120\b", out), out  # DRIVE_STATUS, 0x120
            continue
        r = subprocess.run(cmd, cwd=tmp_path, env=env, capture_output=True, text=True,
                           timeout=600, check=False)
        assert r.returncode == 0, f"README line {ln.line}: {' '.join(argv)}\n{r.stderr}"
    assert (tmp_path / "out" / "s" / "frames.blf").is_file()
    assert (tmp_path / "out" / "s" / "smoke.mf4").is_file()


def _send_drive_status(channel: str, env: dict[str, str]) -> None:
    """One DRIVE_STATUS frame on the channel, from another process (a python-can node)."""
    code = ("import can, time, cantools\n"
            "from rig import protocols\n"
            "m = protocols.database('drive').get_message_by_name('DRIVE_STATUS')\n"
            "data = m.encode({'state': 2, 'ctrl_mode': 1, 'fw_mode': 0, 'fault_code': 0,"
            " 'cmd_status': 0, 'rx_rejected': 0, 'polarity_ok': 1, 'est_valid': 1})\n"
            f"with can.Bus(interface='unixcan', channel={channel!r}) as bus:\n"
            "    bus.send(can.Message(arbitration_id=m.frame_id, is_extended_id=False,"
            " data=data))\n")
    subprocess.run([sys.executable, "-c", code], env=env, check=True, timeout=EVENT_S)


def _nodes(channel: str) -> int:
    return len(list(unixcan.channel_dir(channel).glob("*.sock")))


def _await_join(p: subprocess.Popen[bytes] | subprocess.Popen[str], channel: str,
                before: int) -> None:
    """Waits until the program started has joined the channel (its socket is there)."""
    wait_until(lambda: p.poll() is not None or _nodes(channel) > before,
               f"{channel}: the program joining the channel", poll_s=0.02)


def _until_interrupted(cmd: list[str], cwd: Path, env: dict[str, str]) -> str:
    """Starts a logger, sends it a frame once it is on the channel, interrupts it as a user
    would (Ctrl-C) once it has printed the frame."""
    channel = _channel_of(cmd)
    before = _nodes(channel)
    p = subprocess.Popen(cmd, cwd=cwd, env={**env, "PYTHONUNBUFFERED": "1"},
                         stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    assert p.stdout is not None
    out = b""
    try:
        _await_join(p, channel, before)
        _send_drive_status(channel, env)
        deadline = time.monotonic() + EVENT_S
        while not re.search(rb"ID:\s+0*120\b", out) and p.poll() is None \
                and time.monotonic() < deadline:
            if select.select([p.stdout], [], [], 0.1)[0]:
                out += os.read(p.stdout.fileno(), 65536)
    finally:
        p.send_signal(signal.SIGINT)
        rest, _ = p.communicate(timeout=EVENT_S)
    text = (out + rest).decode(errors="replace")
    assert "error" not in text.lower(), text
    return text


def _channel_of(cmd: list[str]) -> str:
    return cmd[cmd.index("-c") + 1]


def _on_a_terminal(cmd: list[str], cwd: Path, env: dict[str, str]) -> str:
    """Runs a curses program on a pseudo-terminal, sends a frame, quits it with 'q'; the
    screen it drew."""
    master, slave = os.openpty()
    term_env = {**env, "TERM": "xterm", "LINES": "40", "COLUMNS": "120"}
    channel = _channel_of(cmd)
    before = _nodes(channel)
    p = subprocess.Popen(cmd, cwd=cwd, env=term_env, stdin=slave, stdout=slave, stderr=slave,
                         start_new_session=True)
    os.close(slave)
    screen = b""

    def read_for(seconds: float, until: bytes | None = None) -> None:
        """Reads the screen for `seconds`, or until `until` is on it."""
        nonlocal screen
        end = time.monotonic() + seconds
        while time.monotonic() < end and (until is None or until not in screen):
            ready, _, _ = select.select([master], [], [], 0.1)
            if ready:
                try:
                    screen += os.read(master, 65536)
                except OSError:
                    return

    try:
        _await_join(p, channel, before)
        _send_drive_status(channel, env)
        read_for(EVENT_S, until=b"state: POLARITY")
        os.write(master, b"q")
        assert p.wait(timeout=EVENT_S) == 0
        read_for(0.3)
    finally:
        if p.poll() is None:
            p.kill()
            p.wait()
        os.close(master)
    return screen.decode(errors="replace")
