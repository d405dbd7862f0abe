"""Run a command inside a virtme-ng VM whose kernel has SocketCAN, with vcan0 up.

The host kernel of the rig's CI machines has no CAN support; Debian's stock kernel
(``linux-image-amd64``) has vcan and can-raw. virtme-ng boots it over the host's own root
file system (read-only) with the checkout mounted writable, so the VM sees the same venv and
binaries. KVM hangs on these machines, so the VM runs under TCG unless told otherwise.
"""

from __future__ import annotations

import glob
import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

# Variables the command inside the VM should see as on the host.
_FORWARDED_ENV = re.compile(r"^(HIL_|UNIXCAN_|PYTEST_|CI$|PYTHONPATH$|TERM$)")


def find_kernel() -> Path:
    """The newest Debian kernel image under /boot."""
    images = sorted(glob.glob("/boot/vmlinuz-*"), key=_version_key)
    if not images:
        raise FileNotFoundError(
            "no kernel image in /boot; install Debian's linux-image-amd64 (./hil install does)"
        )
    return Path(images[-1])


def _version_key(path: str) -> list[int]:
    return [int(n) for n in re.findall(r"\d+", Path(path).name)]


def find_vng() -> str:
    """vng (virtme-ng) from this Python's venv or PATH; it needs virtme-run beside it."""
    bindir = Path(sys.executable).parent
    for candidate in (bindir / "vng", shutil.which("vng")):
        if candidate and Path(candidate).is_file():
            return str(candidate)
    raise FileNotFoundError("virtme-ng not installed: pip install 'sensorless-hil[vm]'")


def guest_script(command: list[str], workdir: Path, channels: list[str]) -> str:
    """Shell run as the VM's init job: vcan interfaces up, environment, then the command."""
    lines = ["set -e", "modprobe vcan"]
    for ch in channels:
        q = shlex.quote(ch)
        lines += [f"ip link add dev {q} type vcan", f"ip link set dev {q} mtu 72 up"]
    bindir = Path(sys.executable).parent
    env = {k: v for k, v in os.environ.items() if _FORWARDED_ENV.match(k)}
    env["HIL_IN_VM"] = "1"
    env["PATH"] = f"{bindir}:/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin"
    lines += [f"export {k}={shlex.quote(v)}" for k, v in sorted(env.items())]
    lines += [f"cd {shlex.quote(str(workdir))}", "set +e", shlex.join(command)]
    return "\n".join(lines) + "\n"


def vm_command(command: list[str], workdir: Path, rwdirs: list[Path], channels: list[str],
               memory: str, cpus: int, kvm: bool, kernel: Path | None) -> list[str]:
    args = [find_vng(), "--run", str(kernel or find_kernel()), "--force-9p",
            "--memory", memory, "--cpus", str(cpus)]
    if not kvm:
        args.append("--disable-kvm")
    for d in rwdirs:
        args += ["--rwdir", str(d)]
    args += ["--exec", guest_script(command, workdir, channels)]
    return args


def run_in_vm(command: list[str], workdir: Path | None = None, rwdirs: list[Path] | None = None,
              channels: list[str] | None = None, memory: str = "2G", cpus: int = 2,
              kvm: bool = False, kernel: Path | None = None) -> int:
    """Runs command in the VM and returns its exit code."""
    if not command:
        raise ValueError("no command to run in the VM")
    work = (workdir or Path.cwd()).resolve()
    dirs = [d.resolve() for d in (rwdirs or [work])]
    args = vm_command(command, work, dirs, channels or ["vcan0"], memory, cpus, kvm, kernel)
    env = dict(os.environ)
    env["PATH"] = f"{Path(sys.executable).parent}:{env.get('PATH', '')}"  # vng calls virtme-run
    # The VM's console is relayed through a pipe: given our stdout directly, qemu truncates
    # it when it is a file, and a caller's log would lose everything written before.
    proc = subprocess.Popen(args, env=env, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT)
    assert proc.stdout is not None
    out = sys.stdout.buffer
    while chunk := proc.stdout.read1(65536):
        out.write(chunk)
        out.flush()
    return proc.wait()
