"""The unixcan folder belongs to its user, by one rule on both sides (docs/interfaces.md).

C (hilbus, through hilbus_tool) and Python (rig.bus.unixcan) must pick the same folder and
refuse the same things: a symlinked folder, a channel name that is a path, a base others can
write to, a folder of another user. A second uid can neither send into nor read from a run.
"""

from __future__ import annotations

import json
import os
import shutil
import socket
import stat
import subprocess
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

import can
import pytest
from waits import EVENT_S

from rig import _paths
from rig.bus import unixcan


def tool() -> str:
    try:
        return str(_paths.binary("hilbus_tool"))
    except FileNotFoundError as exc:
        pytest.skip(f"hilbus_tool not built: {exc}")


def c_dir(channel: str, env: dict[str, str]) -> tuple[int, str, str]:
    """What hilbus picks and does for a channel: (exit code, folder, error)."""
    done = subprocess.run([tool(), "dir", "--bus", "unixcan", "--channel", channel],
                          capture_output=True, text=True, env=env, timeout=30, check=False)
    folder = json.loads(done.stdout)["dir"] if done.returncode == 0 else ""
    return done.returncode, folder, done.stderr


@pytest.fixture
def short_tmp() -> Iterator[Path]:
    """A fresh folder with a short path: a socket address holds 108 bytes."""
    path = Path(tempfile.mkdtemp(prefix="ucd-", dir="/tmp"))
    yield path
    shutil.rmtree(path, ignore_errors=True)


@pytest.fixture
def clean_env(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    for name in ("UNIXCAN_DIR", "XDG_RUNTIME_DIR", "UNIXCAN_GROUP"):
        monkeypatch.delenv(name, raising=False)
    yield


def test_c_and_python_pick_the_same_folder(short_tmp: Path, clean_env: None,
                                           monkeypatch: pytest.MonkeyPatch) -> None:
    xdg = short_tmp / "xdg"
    xdg.mkdir(mode=0o700)
    cases = [
        ({"UNIXCAN_DIR": str(short_tmp / "explicit")}, short_tmp / "explicit"),
        ({"XDG_RUNTIME_DIR": str(xdg)}, xdg / "unixcan"),
        ({"XDG_RUNTIME_DIR": "relative/dir"}, Path(f"/tmp/unixcan-{os.geteuid()}")),
        ({}, Path(f"/tmp/unixcan-{os.geteuid()}")),
    ]
    for extra, want in cases:
        env = {k: v for k, v in os.environ.items()
               if k not in ("UNIXCAN_DIR", "XDG_RUNTIME_DIR")} | extra
        for k, v in extra.items():
            monkeypatch.setenv(k, v)
        assert unixcan.base_dir() == want, extra
        if want.is_relative_to(short_tmp):  # do not create folders outside the test's own
            rc, folder, err = c_dir("agree", env)
            assert rc == 0, err
            assert Path(folder) == want / "agree"
            assert stat.S_IMODE(os.lstat(want).st_mode) == 0o700
            assert stat.S_IMODE(os.lstat(folder).st_mode) == 0o700
        for k in extra:
            monkeypatch.delenv(k)


@pytest.mark.parametrize("name", ["..", ".", "a/b", "../up", "-x", ".hidden", "", "a b",
                                  "x" * 64])
def test_channel_names_are_plain_names(name: str, short_tmp: Path,
                                       monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("UNIXCAN_DIR", str(short_tmp / "uc"))
    with pytest.raises(can.CanInitializationError, match="invalid channel name"):
        can.Bus(interface="unixcan", channel=name)
    if name:
        rc, _, err = c_dir(name, dict(os.environ))
        assert rc == 1 and "invalid channel name" in err
    assert not (short_tmp / "uc").exists() or not any((short_tmp / "uc").iterdir())


def _stale_socket(path: Path) -> None:
    s = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    s.bind(str(path))
    s.close()


def test_symlinked_folders_are_refused_and_nothing_outside_is_removed(
        short_tmp: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    victim = short_tmp / "victim"
    victim.mkdir(mode=0o700)
    stale = victim / "1-0.sock"
    _stale_socket(stale)
    base = short_tmp / "uc"
    base.mkdir(mode=0o700)
    (base / "evil").symlink_to(victim)
    monkeypatch.setenv("UNIXCAN_DIR", str(base))
    with pytest.raises(can.CanInitializationError, match="symbolic link"):
        can.Bus(interface="unixcan", channel="evil")
    rc, _, err = c_dir("evil", dict(os.environ))
    assert rc == 1 and "symbolic link" in err
    assert stale.exists()
    monkeypatch.setenv("UNIXCAN_DIR", str(short_tmp / "baselink"))
    (short_tmp / "baselink").symlink_to(victim)
    with pytest.raises(can.CanInitializationError, match="symbolic link"):
        can.Bus(interface="unixcan", channel="x")
    rc, _, err = c_dir("x", dict(os.environ))
    assert rc == 1 and "symbolic link" in err
    assert stale.exists() and not (victim / "x").exists()


def _nobody() -> tuple[int, int]:
    import pwd

    try:
        entry = pwd.getpwnam("nobody")
    except KeyError:
        pytest.skip("no user nobody")
    return entry.pw_uid, entry.pw_gid


@pytest.mark.parametrize("above", ["link_of_another_user", "folder_of_another_user",
                                   "folder_others_write"])
def test_folders_above_the_base_must_be_trusted(above: str, short_tmp: Path,
                                                monkeypatch: pytest.MonkeyPatch) -> None:
    """Issue 23.18: a symbolic link above UNIXCAN_DIR was followed wherever it pointed (the
    bus folder then lies where another user can move it away or put another in its place).
    C and Python now refuse a folder above the base that another user owns or can write,
    and a link there that is not root's or this user's."""
    if above != "folder_others_write" and os.geteuid() != 0:
        pytest.skip("needs root to make a file of another user")
    victim = short_tmp / "theirs"
    victim.mkdir(mode=0o755)
    if above == "link_of_another_user":
        uid, gid = _nobody()
        os.chown(victim, uid, gid)
        (short_tmp / "link").symlink_to(victim)
        os.lchown(short_tmp / "link", uid, gid)
        parent, why = short_tmp / "link", "symbolic link of uid"
    elif above == "folder_of_another_user":
        uid, gid = _nobody()
        os.chown(victim, uid, gid)
        parent, why = victim, "belongs to uid"
    else:
        victim.chmod(0o777)
        parent, why = victim, "writable by other users"
    monkeypatch.setenv("UNIXCAN_DIR", str(parent / "uc"))
    with pytest.raises(can.CanInitializationError, match=why):
        can.Bus(interface="unixcan", channel="x")
    rc, _, err = c_dir("x", dict(os.environ))
    assert rc == 1 and why in err and "above the bus folder" in err, err
    assert not any(victim.iterdir())  # nothing was made there


def test_trusted_folders_above_the_base_are_used(short_tmp: Path,
                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    """The same rule lets the usual places through: a link of this user (as /var/run ->
    /run is root's), a sticky folder others write to (as /tmp), folders to be made."""
    real = short_tmp / "real"
    real.mkdir(mode=0o755)
    (short_tmp / "mine").symlink_to(real)
    sticky = short_tmp / "sticky"
    sticky.mkdir()
    sticky.chmod(0o1777)
    for parent in (short_tmp / "mine", sticky, short_tmp / "new" / "deeper"):
        monkeypatch.setenv("UNIXCAN_DIR", str(parent / "uc"))
        can.Bus(interface="unixcan", channel="ok").shutdown()
        rc, folder, err = c_dir("ok", dict(os.environ))
        assert rc == 0, err
        assert Path(folder).resolve() == (parent / "uc" / "ok").resolve()
    assert (real / "uc" / "ok").is_dir()
    assert stat.S_IMODE((short_tmp / "new").stat().st_mode) == 0o700


def test_modes_and_a_base_others_can_write(short_tmp: Path,
                                           monkeypatch: pytest.MonkeyPatch) -> None:
    base = short_tmp / "uc"
    monkeypatch.setenv("UNIXCAN_DIR", str(base))
    bus = can.Bus(interface="unixcan", channel="m")
    try:
        assert stat.S_IMODE(base.stat().st_mode) == 0o700
        assert stat.S_IMODE((base / "m").stat().st_mode) == 0o700
        socks = list((base / "m").glob("*.sock"))
        assert len(socks) == 1 and stat.S_IMODE(socks[0].stat().st_mode) == 0o600
    finally:
        bus.shutdown()
    (base / "m").chmod(0o755)  # an old, looser channel folder is tightened
    can.Bus(interface="unixcan", channel="m").shutdown()
    assert stat.S_IMODE((base / "m").stat().st_mode) == 0o700
    base.chmod(0o777)
    with pytest.raises(can.CanInitializationError, match="writable by other users"):
        can.Bus(interface="unixcan", channel="m")
    rc, _, err = c_dir("m", dict(os.environ))
    assert rc == 1 and "writable by other users" in err


def test_a_group_asked_for_gives_0770_and_0660(short_tmp: Path,
                                               monkeypatch: pytest.MonkeyPatch) -> None:
    gid = os.getegid()
    monkeypatch.setenv("UNIXCAN_DIR", str(short_tmp / "uc"))
    monkeypatch.setenv("UNIXCAN_GROUP", str(gid))
    bus = can.Bus(interface="unixcan", channel="g")
    try:
        folder = short_tmp / "uc" / "g"
        assert stat.S_IMODE(folder.stat().st_mode) == 0o770 and folder.stat().st_gid == gid
        sock = next(folder.glob("*.sock"))
        assert stat.S_IMODE(sock.stat().st_mode) == 0o660 and sock.stat().st_gid == gid
        rc, folder_c, err = c_dir("g", dict(os.environ))
        assert rc == 0, err
        assert stat.S_IMODE(Path(folder_c).stat().st_mode) == 0o770
    finally:
        bus.shutdown()


def test_malformed_datagrams_are_counted_not_delivered(short_tmp: Path,
                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("UNIXCAN_DIR", str(short_tmp / "uc"))
    bus = can.Bus(interface="unixcan", channel="d")
    try:
        target = str(next((short_tmp / "uc" / "d").glob("*.sock")))
        s = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        bad = [b"", b"x", bytes(15), bytes(17), bytes(71), bytes(73), bytes(200),
               # 72 bytes with len 255, 65 and 13 (no FD length); 16 bytes with len 9
               bytes([0x10, 0, 0, 0, 255]) + bytes(67),
               bytes([0x10, 0, 0, 0, 65]) + bytes(67),
               bytes([0x10, 0, 0, 0, 13]) + bytes(67),
               bytes([0x10, 0, 0, 0, 9]) + bytes(11)]
        good = bytes([0x42, 0, 0, 0, 64, 4, 0, 0]) + bytes(range(64))
        got: list[can.Message] = []
        for d in [*bad, good]:
            s.sendto(d, target)
            m = bus.recv(0.05)
            while m is not None:
                got.append(m)
                m = bus.recv(0.05)
        s.close()
        assert [(m.arbitration_id, len(m.data)) for m in got] == [(0x42, 64)]
        assert bus.stats["rx_malformed"] == len(bad)  # type: ignore[attr-defined]
    finally:
        bus.shutdown()


def test_only_own_sockets_are_peers(short_tmp: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("UNIXCAN_DIR", str(short_tmp / "uc"))
    bus = can.Bus(interface="unixcan", channel="p")
    try:
        folder = short_tmp / "uc" / "p"
        (folder / "file.sock").write_text("not a socket")
        _stale_socket(folder / "77-0.sock")
        bus.send(can.Message(arbitration_id=1, data=b"\1", is_extended_id=False))
        assert (folder / "file.sock").exists()
        assert not (folder / "77-0.sock").exists()  # our own dead node: removed
        assert bus.stats["foreign_entries"] >= 1  # type: ignore[attr-defined]
    finally:
        bus.shutdown()


INTRUDER = r"""
import os, socket, sys
folder = sys.argv[1]
out = {}
try:
    os.listdir(folder)
    out["list"] = "ok"
except OSError as e:
    out["list"] = e.strerror
s = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
frame = bytes([0x11, 0, 0, 0, 64, 4, 0, 0]) + bytes(64)
for name in sys.argv[2:]:
    try:
        s.sendto(frame, os.path.join(folder, name))
        out[name] = "sent"
    except OSError as e:
        out[name] = e.strerror
try:
    os.makedirs(os.path.join(folder, "..", "intruder"), exist_ok=True)
    out["mkdir"] = "ok"
except OSError as e:
    out["mkdir"] = e.strerror
import json
print(json.dumps(out))
"""


@pytest.mark.skipif(os.geteuid() != 0, reason="needs root to run a second uid (setpriv)")
def test_a_second_user_can_neither_send_nor_read(short_tmp: Path,
                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    setpriv = shutil.which("setpriv")
    if setpriv is None:
        pytest.skip("setpriv (util-linux) not installed")
    # the run's folder in a place the other user could reach if the modes allowed it
    base = Path(f"/tmp/unixcan-2nd-uid-{os.getpid()}")
    monkeypatch.setenv("UNIXCAN_DIR", str(base))
    bus = can.Bus(interface="unixcan", channel="run")
    c_node = subprocess.Popen([tool(), "recv", "--bus", "unixcan", "--channel", "run",
                               "--count", "1", "--timeout-ms", str(round(EVENT_S * 1e3))],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        folder = base / "run"
        deadline = time.monotonic() + EVENT_S
        while len(list(folder.glob("*.sock"))) < 2 and time.monotonic() < deadline:
            time.sleep(0.01)
        names = sorted(p.name for p in folder.glob("*.sock"))
        assert len(names) == 2
        done = subprocess.run(
            [setpriv, "--reuid=nobody", "--regid=nogroup", "--clear-groups",
             shutil.which("python3", path="/usr/bin:/bin") or "python3",
             "-c", INTRUDER, str(folder), *names],
            capture_output=True, text=True, timeout=60, check=False, cwd="/")
        assert done.returncode == 0, done.stderr
        result = json.loads(done.stdout)
        assert result["list"] == "Permission denied"
        for name in names:
            assert result[name] == "Permission denied", result
        assert result["mkdir"] == "Permission denied"
        # and nothing reached the run's nodes
        assert bus.recv(0.2) is None
        c_node.terminate()  # (its own time-out is a ceiling: it must outlast the intruder)
        out, _ = c_node.communicate(timeout=EVENT_S)
        assert '"id"' not in out
    finally:
        if c_node.poll() is None:
            c_node.kill()
            c_node.wait()
        bus.shutdown()
        shutil.rmtree(base, ignore_errors=True)
