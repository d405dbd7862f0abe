"""plant_rt in real time against the C stand-in firmware (pwm_responder).

Timing on a loaded two-core machine is whatever it is, so these tests check the counting
logic against the plant's own per-period trace, never timing figures. With --trace-vio the
trace holds, per period k, the VIO_PWM frames taken from the bus when period k started, then
ADC(k), BENCH_TRUTH(k) and BENCH_TRUTH_MAG(k). The responder's `cycle6` commands put a
different set of legs high at tick 0 in consecutive periods, so the phase voltages in
BENCH_TRUTH(k) tell which command period k ran with.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import pytest
from plant_peer import PlantProcess, Responder, read_trace

# high legs of the responder's cycle6 command for PWM(j): HIGH[j % 6]
HIGH = [(1, 0, 0), (1, 1, 0), (0, 1, 0), (0, 1, 1), (0, 0, 1), (1, 0, 1)]


@dataclass
class Period:
    drained: list[int]  # periods of the VIO_PWM frames taken at this period's start
    legs: tuple[int, int, int] | None  # high legs at tick 0, None with all phases at 0 V


def periods_from_trace(path: Path) -> list[Period]:
    out: list[Period] = []
    drained: list[int] = []
    for r in read_trace(path):
        if r.name == "VIO_PWM":
            drained.append(int(r.signals["period"]))
        elif r.name == "BENCH_TRUTH":
            assert int(r.signals["period"]) == len(out), "a period missing in the trace"
            u = (r.signals["ua"], r.signals["ub"], r.signals["uc"])
            legs = None
            if max(abs(x) for x in u) >= 1.0:
                legs = (int(u[0] > 0), int(u[1] > 0), int(u[2] > 0))
            out.append(Period(drained, legs))
            drained = []
    return out


def check_counting(periods: list[Period], counters: dict[str, object]) -> list[int]:
    """Checks the counters and the loaded commands against the trace; returns the late
    periods."""
    late = [k for k in range(1, len(periods)) if k not in periods[k].drained]
    stale = sum(1 for k, p in enumerate(periods) for j in p.drained if j < k)
    assert counters["late_cmds"] == len(late)
    rejects = counters["rejects"]
    assert isinstance(rejects, dict)
    assert rejects["stale_period"] == stale
    assert counters["rejected"] == stale  # nothing else was wrong with the frames
    assert periods[0].legs is None  # start-up: gates off at standstill
    for k in range(1, len(periods)):
        if k in late:
            # the old compare values stay loaded
            assert periods[k].legs == periods[k - 1].legs, k
        else:
            assert periods[k].legs == HIGH[k % 6], k
    return late


@pytest.mark.parametrize("spin_us", [0, 30])
def test_late_updates_keep_the_old_command(transport: str, channel: str, tmp_path: Path,
                                          spin_us: int) -> None:
    """Every 4th PWM is sent 250 us after its ADC, i.e. after its period started. With
    --rt-spin-us the plant polls the bus for the last 30 us before each period instead of
    sleeping: the same rules apply to the frames it takes while spinning."""
    n = 600
    trace = tmp_path / "rt.trace"
    responder = Responder(transport, channel, tmp_path, "--pattern", "cycle6",
                          "--late-every", "4", "--late-us", "250")
    try:
        plant = PlantProcess(transport, channel, tmp_path, "--realtime", "--profile", "ideal",
                             "--max-periods", str(n), "--trace", str(trace), "--trace-vio",
                             "--rt-spin-us", str(spin_us))
        result = plant.wait(30.0)
    finally:
        answers = responder.stop()
    assert result.returncode == 0, result.stderr
    c = result.counters
    assert c["mode"] == "realtime" and c["periods"] == n
    assert answers["late_answers"] > 0  # fewer than n/4 if ADC frames found it busy (tx_drops)
    periods = periods_from_trace(trace)
    assert len(periods) == n
    late = check_counting(periods, c)
    deliberate = range(4, n, 4)
    # A deliberately late PWM(j) leaves 250 us after ADC(j-1), and period j starts at most
    # one period after that ADC was sent: it can only be in time if the plant itself was
    # held up between sending ADC(j-1) and reading the clock.
    assert sum(1 for j in deliberate if j in late) >= 0.9 * len(deliberate)
    assert c["max_late_us"] > 0
    assert c["wake_late_us"]["n"] == n


def test_overruns_counted_and_grid_slips(transport: str, channel: str, tmp_path: Path) -> None:
    """A solver step of 0.1 us makes every period cost far more than 100 us of compute."""
    n = 30
    trace = tmp_path / "rt.trace"
    responder = Responder(transport, channel, tmp_path, "--pattern", "cycle6")
    try:
        plant = PlantProcess(transport, channel, tmp_path, "--realtime", "--profile", "ideal",
                             "--set", "solver.max_step_s=1e-7", "--max-periods", str(n),
                             "--trace", str(trace), "--trace-vio")
        result = plant.wait(60.0)
    finally:
        responder.stop()
    assert result.returncode == 0, result.stderr
    c = result.counters
    assert c["periods"] == n
    assert c["overruns"] == n  # every period ends after the next one should have started
    assert c["slipped_periods"] >= c["overruns"]
    check_counting(periods_from_trace(trace), c)
