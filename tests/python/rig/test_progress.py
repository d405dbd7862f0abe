"""The one progress display (rig.run.progress) of runs, suites, sweeps and baseline records
(issue 39.2): k/N, elapsed, an ETA from the work done ("--" before there is any, never "nan"),
the current scenario's simulated time and speed; quiet where stderr is not a terminal."""

from __future__ import annotations

import io
import os
import pty
import select
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from rig.run import progress

SMOKE = Path(__file__).resolve().parents[3] / "rig" / "scenarios" / "smoke.toml"


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


@pytest.fixture
def clock(monkeypatch: pytest.MonkeyPatch) -> Clock:
    c = Clock()
    monkeypatch.setattr(progress.time, "monotonic", c)
    return c


def test_eta_from_the_work_done(clock: Clock) -> None:
    d = progress.Display("paper", 3, work=[1.0, 2.0, 1.0], enabled=True, terminal=False)
    assert "ETA --" in d.text() and "nan" not in d.text()  # nothing done: no pace yet
    d.start("a", 1.0)
    clock.now += 10.0
    d.at(0.5, 980.0, 1.25)  # half of the first (1 of 4 s of work): 1/8 in 10 s
    assert d.fraction() == pytest.approx(0.125)
    assert d.eta_s() == pytest.approx(70.0)
    text = d.text()
    assert "elapsed 0:10" in text and "ETA 1:10" in text
    assert "a: t=0.500/1 s, 0.05x real time, 980 r/min, err +1.25°" in text
    d.done("a", True)
    clock.now += 10.0
    d.start("b", 2.0)
    d.at(2.0)
    assert d.fraction() == pytest.approx(0.75) and d.eta_s() == pytest.approx(20 / 3)
    d.done("b", False)
    assert d.head() == "paper 2/3 scenarios" and "1 not passed" in d.text()


def test_quiet_where_nobody_watches_and_said_lines_still_said() -> None:
    out = io.StringIO()
    d = progress.Display("x", 2, enabled=True, stream=out)  # a StringIO is no terminal
    with d:
        d.start("a", 1.0)
        d.at(0.5, force=True)
        d.done("a", True, "a: PASS")
    assert out.getvalue() == "a: PASS\n"
    silent = io.StringIO()
    with progress.Display("x", 1, enabled=False, stream=silent) as d:
        d.done("a", True, "a: PASS")
    assert silent.getvalue() == ""


def test_on_a_terminal_it_draws_k_of_n_and_the_current_run(clock: Clock) -> None:
    out = io.StringIO()
    with progress.Display("suite", 2, work=[0.5, 0.5], stream=out, terminal=True) as d:
        with progress.item("smoke", 0.5) as shown:  # a run inside reports to the suite's
            assert shown is d
            clock.now += 1.0
            d.at(0.25, 300.0, force=True)
        d.done("smoke", True, "smoke: PASS")
    text = out.getvalue()
    assert "suite 0/2 scenarios" in text and "smoke: t=0.250/0.5 s" in text
    assert "smoke: PASS" in text and "ETA 0:03" in text
    # a lone run has a display of its own, closed with it
    with progress.item("lone", 1.0, enabled=False) as own:
        assert own is not d and progress.active() is own
    assert progress.active() is None


def test_a_suite_on_a_terminal_shows_the_display(tmp_path: Path) -> None:
    """End to end under a pseudo-terminal: a two-scenario suite in process draws k/N, the
    elapsed time and an ETA, and never "nan"."""
    suite = tmp_path / "pair.toml"
    suite.write_text(textwrap.dedent(f"""\
        name = "pair"
        scenarios = ["{SMOKE}", "{SMOKE}@paper"]
        """))
    leader, follower = pty.openpty()
    proc = subprocess.Popen([sys.executable, "-m", "rig", "run", str(suite), "--bus", "inproc",
                             "--no-record", "--no-figures", "--out", str(tmp_path / "o")],
                            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                            stderr=follower, env={**os.environ, "COLUMNS": "200"})
    os.close(follower)
    seen = b""
    while True:
        ready, _, _ = select.select([leader], [], [], 300)
        assert ready, "no output within 300 s"
        try:
            chunk = os.read(leader, 65536)
        except OSError:  # the terminal closed with the program
            break
        if not chunk:
            break
        seen += chunk
    os.close(leader)
    assert proc.wait(timeout=60) == 0
    text = seen.decode(errors="replace")
    assert "pair 0/2 scenarios" in text or "pair 1/2 scenarios" in text, text[-2000:]
    assert "elapsed" in text and "ETA" in text and "nan" not in text
    assert "smoke: t=" in text
