"""A copy of the source tree that mutants are built in: the C programs and tests configured
once (Release, the C tests on, no sanitizers: a mutant is judged by its behaviour, and the
in-process bench must load into this Python), each mutant then an incremental rebuild."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

from rig import _paths
from rig.regression.mutation.catalogue import Mutant, inside, read_text

# what a mutant build does not need (large, or outputs)
SKIP_PREFIXES = ("tests/fuzz/corpus/", "docs/", "out/", "build/", ".venv/")


class BuildError(RuntimeError):
    pass


@dataclass
class Step:
    ok: bool
    log: str
    seconds: float


def _run(cmd: list[str], cwd: Path, env: dict[str, str] | None = None,
         timeout: float = 1800.0) -> Step:
    import time

    t0 = time.monotonic()
    try:
        p = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True,
                           timeout=timeout, check=False)
        out = (p.stdout or "") + (p.stderr or "")
        return Step(p.returncode == 0, out, time.monotonic() - t0)
    except subprocess.TimeoutExpired as exc:
        return Step(False, f"timed out after {timeout:.0f} s: {' '.join(cmd)}\n{exc}",
                    time.monotonic() - t0)


def tracked_files(repo: Path) -> list[str]:
    """The files of the checkout as git sees them (tracked and new, not ignored)."""
    p = subprocess.run(["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
                       cwd=repo, capture_output=True, check=False)
    if p.returncode != 0:
        raise BuildError(f"git ls-files failed in {repo}: {p.stderr.decode(errors='replace')}")
    return [f for f in p.stdout.decode().split("\0") if f and not f.startswith(SKIP_PREFIXES)]


class MutationTree:
    """``work/src``: the checkout's files; ``work/build``: their build."""

    def __init__(self, work: Path, repo: Path | None = None, jobs: int = 2) -> None:
        self.work = work
        self.repo = repo or _paths.repo_dir()
        self.src = work / "src"
        self.build = work / "build"
        self.jobs = jobs

    @property
    def bin_dir(self) -> Path:
        return self.build / "bin"

    def copy(self) -> None:
        if self.src.exists():
            shutil.rmtree(self.src)
        for rel in tracked_files(self.repo):
            src = self.repo / rel
            if not src.is_file():
                continue  # deleted in the work tree
            dst = self.src / rel
            dst.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dst)

    def configure(self) -> Step:
        return _run(["cmake", "-S", str(self.src), "-B", str(self.build), "-DHIL_TESTS=ON",
                     "-DCMAKE_BUILD_TYPE=Release", f"-DPython3_EXECUTABLE={sys.executable}"],
                    self.work)

    def compile(self) -> Step:
        return _run(["cmake", "--build", str(self.build), f"-j{self.jobs}"], self.work)

    def ctest(self) -> Step:
        return _run(["ctest", "--test-dir", str(self.build), f"-j{self.jobs}",
                     "--output-on-failure", "--timeout", "300"], self.work)

    def apply(self, m: Mutant) -> str:
        """Writes the mutant into the copy (only a regular file inside it: checked again
        here, against the copy); returns the file's original text."""
        path = inside(self.src, m.file)
        original = read_text(path, m.file)
        path.write_text(m.apply(original), encoding="utf-8")
        return original

    def restore(self, m: Mutant, original: str) -> None:
        inside(self.src, m.file).write_text(original, encoding="utf-8")

    def env(self) -> dict[str, str]:
        """The environment that makes the rig use this build's programs and libraries."""
        return {**os.environ, "HIL_BIN_DIR": str(self.bin_dir)}
