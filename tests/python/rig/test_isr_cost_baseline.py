"""The ISR's cost as a value of the gate (issue 40): the instructions per period on the target
have a 5 % relative floor of their own, a value 5 % worse than its baseline is flagged and
confirmed at fresh seeds, less is not, and the flag says which step of fw_core_isr grew."""

from __future__ import annotations

import math
import random
from typing import Any

import pytest

from rig.regression import baseline, confirm
from rig.regression.baseline import LOWER, REGRESSED, UNCHANGED, Band, Record, SeedResult
from rig.scenario import Criterion

STEPS = {"entry": 66.0, "take_period": 325.0, "protect": 563.0, "estimate": 5394.0,
         "outputs": 1594.0, "torque_model": 501.0, "voltage_mean": 16.0}
TOTAL = sum(STEPS.values())


def _seeds(rng: random.Random, scale: float = 1.0, grow: str = "", by: float = 0.0
           ) -> list[dict[str, float]]:
    """Per-step counts at 8 seeds: a spread of 0.3 % (the input the noise draws), one step
    grown by ``by`` instructions."""
    out = []
    for _ in range(8):
        d = {k: round(v * scale * (1 + rng.gauss(0, 0.003))) for k, v in STEPS.items()}
        if grow:
            d[grow] += by
        out.append(d)
    return out


def _record(details: list[dict[str, float]]) -> Record:
    values = [sum(d.values()) for d in details]
    return Record("ISR worst", "isr_instructions_max", (0.0, 0.1), {}, "instructions", LOWER,
                  "pass", Band.of(values, "instructions"), "value",
                  baseline._mean_detail(details))


def test_instructions_have_a_five_percent_floor() -> None:
    assert baseline.floor_of(9000.0, "instructions") == 450.0
    assert baseline.floor_of(9000.0, "deg") == 90.0  # (1 % for any other unit)
    assert baseline.floor_of(10.0, "instructions") == 1.0  # the unit's resolution


def test_five_percent_more_is_flagged_four_is_not() -> None:
    """A band drawn from seeds 0.3 % apart is the floor (5 % of the mean): the same firmware
    at another seed and 4 % more work stay inside, 6 % more is beyond it."""
    rng = random.Random(1)
    rec = _record(_seeds(rng))
    assert math.isclose(rec.band.hi - rec.band.value, rec.band.floor, rel_tol=1e-4)
    for grow, cls in ((0.0, UNCHANGED), (0.04, UNCHANGED), (0.06, REGRESSED)):
        run = _seeds(rng, grow="estimate", by=grow * TOTAL)[0]
        assert rec.band.classify(sum(run.values()), LOWER) == cls, grow


def test_the_flag_names_the_step_that_grew() -> None:
    rng = random.Random(2)
    rec = _record(_seeds(rng))
    run = _seeds(rng, grow="torque_model", by=0.08 * TOTAL)[0]
    c: dict[str, Any] = {"name": rec.criterion, "metric": rec.metric, "window": [0.0, 0.1],
                         "params": {}, "better": LOWER, "value": sum(run.values()),
                         "detail": run}
    b = rec.judged(c["value"], 8)
    assert b["class"] == REGRESSED
    where = rec.where(c)
    assert where.startswith("moved in torque_model ")
    assert "estimate" not in where  # only the step that moved, not the noise of the others
    # and through the baseline's judgement of a run, the class and the words together
    bl = baseline.Baseline("s", tuple(range(1, 9)), "", {}, {
        "x@paper": baseline.Entry("x@paper", "digest", {rec.criterion: rec})})
    bl.judge("x@paper", "digest", 1, [c])
    assert c["baseline"]["class"] == REGRESSED
    assert c["baseline"]["where"] == where


def test_a_real_five_percent_is_confirmed_noise_is_not() -> None:
    """At fresh seeds: 8 % more work at every seed is confirmed (beyond the 5 % floor the
    rank test moves them back by); the same firmware drawn again is not."""
    rng = random.Random(3)
    rec = _record(_seeds(rng))
    same = [sum(d.values()) for d in _seeds(rng)]
    more = [sum(d.values()) for d in _seeds(rng, grow="estimate", by=0.08 * TOTAL)]
    assert confirm.shift_p(rec, same) > confirm.ALPHA
    assert confirm.shift_p(rec, more) <= confirm.ALPHA


def test_the_detail_goes_through_the_file(monkeypatch: pytest.MonkeyPatch) -> None:
    """Recorded from the seeds' criteria (the mean of each step), written, read back."""
    rng = random.Random(4)
    details = _seeds(rng)
    crit = Criterion("ISR worst", "isr_instructions_max", (0.0, 0.1), math.nan, "report",
                     better="lower")
    runs = {s: [SeedResult([{"name": crit.name, "outcome": "pass", "unit": "instructions",
                             "value": sum(d.values()), "detail": d}])]
            for s, d in zip(range(1, 9), details, strict=True)}

    class Sc:  # the little of a Scenario that build() reads
        name, profile, seeds, criteria = "x", "paper", (), (crit,)

    monkeypatch.setattr(baseline, "setup_digest", lambda sc: "digest")
    b, problems = baseline.build("s", tuple(range(1, 9)), [Sc()], runs, {})  # type: ignore[list-item]
    assert problems == []
    rec = b.entries["x@paper"].records[crit.name]
    for k in STEPS:
        assert math.isclose(rec.detail[k], sum(d[k] for d in details) / 8)
    again = baseline.Baseline.loads(b.dumps())
    back = again.entries["x@paper"].records[crit.name]
    assert back.unit == "instructions" and back.band.floor == rec.band.floor
    assert all(math.isclose(back.detail[k], rec.detail[k], rel_tol=1e-5) for k in STEPS)


def test_a_detail_that_is_not_numbers_is_refused() -> None:
    rng = random.Random(5)
    rec = _record(_seeds(rng))
    bl = baseline.Baseline("s", tuple(range(1, 9)), "", {}, {
        "x@paper": baseline.Entry("x@paper", "digest", {rec.criterion: rec})})
    text = bl.dumps().replace("detail = {entry = ", 'detail = {entry = "a", x = ')
    try:
        baseline.Baseline.loads(text)
    except baseline.BaselineError as exc:
        assert "detail must be a table of finite numbers" in str(exc)
    else:
        raise AssertionError("a detail of strings was accepted")
