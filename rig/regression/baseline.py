"""Baselines: the accepted value of every criterion of a suite's scenarios, with a tolerance
band from their spread over the plant's noise seeds, kept in the repository as reviewed
text (``rig/baselines/<suite>.toml``, written by ``rig baseline record``).

A run compares each criterion's value with its baseline and classifies it:

- ``unchanged``: inside the band;
- ``improved`` / ``regressed``: outside it on the better / worse side, the side given by
  the criterion's comparison (``<=``: lower is better; ``>=``: higher is better);
- ``changed``: outside a band without a better side (``==`` and reported criteria); it
  counts as a regression: the behaviour moved and nobody said which way is good;
- ``stale``: the criterion or the scenario is no longer what was recorded (another metric,
  window or parameters, another plant or drive set-up): it fails until the baseline is
  recorded again, so a baseline never silently judges something else;
- ``new``: no baseline (a scenario or criterion added since).

A scenario decided over its own seeds (``[run] seeds``) reports the worst of them; its
baseline compares the mean of its per-seed values instead, with the band of such a mean
(the worst of a noisy sample moves with any change of rounding, the mean much less).

A stale criterion fails the run at once. A regressed or changed one is a *flag*: one value at
one seed beyond the band, which a harmless change of rounding (it draws the closed loop's
noise again) gives about once in a hundred criteria. ``rig.regression.confirm`` runs the
flagged scenario again at fresh seeds and ranks their values against the baseline's
per-seed values: a confirmed shift stays regressed (or changed) and fails the run, even
inside its limit; an unconfirmed one becomes an ``excursion``, reported, not failing. An
XFAIL is held to its measured value the same way.

The band. Over N seeds (N >= 5) with mean m and sample standard deviation s, the band is
m +- max(t(0.995, N-1) sqrt(1 + 1/N) s, floor), widened to hold every seed's value: the 99 %
prediction interval of one more seed's value (3.7 s for N = 8). The floor, max(1 % of |m|,
the unit's resolution), keeps a band for values the noise barely moves (counters, fault
codes, a speed the drive reaches whatever the noise) from catching round-off; it is also
the margin a confirmed shift must exceed. Every value judged carries its distance from the
mean in band half-widths on the worse side (1: the band's edge) and the chance that one more
seed lands at least that far out (the prediction interval's t distribution). The seed also
dithers the start angle by a thousandth of a degree (Scenario.with_seed), so the noise-free
``ideal`` profile gets the spread its deterministic but sensitive closed loop has. A value
without a number (never detected, no data) counts as the worst value of its side. The file
keeps every seed's value (``values``), which the confirmation ranks against.
"""

from __future__ import annotations

import datetime as dt
import hashlib
import math
import os
import tomllib
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NoReturn

from rig.regression import stats
from rig.results.result import RunResult
from rig.scenario import SEED_KEY, Scenario, positions
from rig.scenario.model import side_of

BASELINE_DIR = Path(__file__).resolve().parents[1] / "baselines"
SCHEMA = "hil-baseline/2"
# files of schema 1 carry no per-seed values: judged, but a flag cannot be confirmed
SCHEMAS = ("hil-baseline/1", SCHEMA)
MIN_SEEDS = 5
PREDICTION = 0.99  # two-sided level of the prediction interval of one more seed
REL_FLOOR = 0.01
# the smallest band half-width per unit: the resolution a value is meaningful to
UNIT_FLOOR = {
    "deg": 0.01, "r/min": 0.01, "%": 0.01, "A": 1e-3, "N*m": 1e-3, "V": 0.01, "mH": 1e-3,
    "Wb": 1e-5, "s": 1e-4, "periods": 1.0, "instructions": 1.0,
}
# units whose least half-width is a larger share of the mean than REL_FLOOR: the ISR's
# instructions per period on the target (rig.target_m4.cost) are exact for a given build and
# input, and what matters of them is a share of the budget; a firmware that costs 5 % more
# in a scenario's median or worst period is a regression (issue 40), less is not
UNIT_REL_FLOOR = {"instructions": 0.05}

UNCHANGED, IMPROVED, REGRESSED, CHANGED, STALE, NEW, MISSING, EXCURSION = (
    "unchanged", "improved", "regressed", "changed", "stale", "new", "missing", "excursion")
CLASSES = (UNCHANGED, IMPROVED, REGRESSED, CHANGED, STALE, NEW, MISSING, EXCURSION)
# classes that fail a run (regressed and changed: confirmed, or not put to a confirmation)
FAILING = (REGRESSED, CHANGED, STALE, MISSING)
# classes a confirmation over fresh seeds decides (rig.regression.confirm)
FLAGGED = (REGRESSED, CHANGED)

LOWER, HIGHER, EITHER = "lower", "higher", "either"


class BaselineError(ValueError):
    """A baseline file that cannot be read, or a record that cannot be made."""


def better_side(c: Mapping[str, Any]) -> str:
    """Which way a criterion's value (a result.json entry) improves: as the criterion says,
    else from its comparison."""
    return str(c.get("better") or side_of(str(c.get("comparison", "<="))))


def entry_key(name: str, profile: str) -> str:
    """A scenario run's key in a baseline: ``<scenario>@<profile>`` (a scenario run alone
    and the same scenario in a suite share it)."""
    return f"{name.split('@', 1)[0]}@{profile}"


def setup_digest(sc: Scenario) -> str:
    """What a scenario run depends on besides its criteria and the seed: profile,
    overrides, drive, speed and load profiles, faults, duration, how many seeds of its own it
    is decided over (not which: any seed is judged). A change here makes the scenario's
    baseline stale."""
    overrides = {k: v for k, v in sorted(sc.overrides.items()) if k != SEED_KEY}
    parts = (sc.profile, overrides, sorted(sc.firmware.items()), sc.ctrl_mode, sc.fw_mode,
             sc.enable_at, sc.iq_ref, sc.i_max, sc.speed_max, sc.step_accel,
             sc.initial_theta_deg, sc.initial_speed_rpm, sc.speed, sc.load, sc.faults,
             sc.duration, len(sc.seeds))
    return hashlib.sha256(repr(parts).encode()).hexdigest()[:12]


# --------------------------------------------------------------------------------------
# The band


def _worst(better: str) -> float:
    return -math.inf if better == HIGHER else math.inf


def _num(v: float | None, better: str) -> float:
    """A value for ordering: no number is the worst of its side."""
    return _worst(better) if v is None or not math.isfinite(v) else float(v)


def _round_out(x: float, up: bool) -> float:
    """``x`` to 6 significant digits, rounded away from the band's inside (so the file's
    short numbers still hold every seed)."""
    if not math.isfinite(x) or x == 0.0:
        return x
    step = 10.0 ** (math.floor(math.log10(abs(x))) - 5)
    r = float(f"{x:.6g}")
    if (up and r < x) or (not up and r > x):
        r = float(f"{(x + step) if up else (x - step):.6g}")
    return r


@dataclass(frozen=True)
class Band:
    """The accepted value of one criterion, its tolerance band and the per-seed values it
    was drawn from."""

    value: float | None  # the mean over the seeds (None: no seed gave a number)
    sd: float
    lo: float
    hi: float
    seeds_min: float | None
    seeds_max: float | None
    # every recorded seed's value (None: no number); None for a schema-1 file
    values: tuple[float | None, ...] | None = None
    floor: float = 0.0  # the band's least half-width: the resolution a move must exceed
    of_mean: bool = False  # the band of a mean of as many values again (own seeds)

    @classmethod
    def of(cls, values: Sequence[float | None], unit: str, of_mean: bool = False) -> Band:
        """The band of one more value like ``values`` (one per seed), or with ``of_mean``
        of the mean of as many values again drawn on the same seeds (a scenario decided
        over its own seeds: its value is the worst of a noisy sample, the mean of that
        sample is what can be compared)."""
        kept = tuple(None if v is None or not math.isfinite(v) else _sig(float(v))
                     for v in values)
        nums = [float(v) for v in values if v is not None and math.isfinite(v)]
        if not nums:
            return cls(None, 0.0, math.nan, math.nan, None, None, kept, 0.0, of_mean)
        n = len(nums)
        m = sum(nums) / n
        sd = math.sqrt(sum((v - m) ** 2 for v in nums) / (n - 1)) if n > 1 else 0.0
        floor = floor_of(m, unit)
        spread = stats.t_quantile(0.5 + PREDICTION / 2, n - 1) * _scale(n, of_mean) * sd \
            if n > 1 else 0.0
        half = max(spread, floor)
        lo, hi = m - half, m + half
        if not of_mean:
            lo, hi = min(lo, min(nums)), max(hi, max(nums))
        return cls(m, sd, _round_out(lo, up=False), _round_out(hi, up=True), min(nums),
                   max(nums), kept, floor, of_mean)

    @property
    def n(self) -> int:
        """How many seeds gave the band a number."""
        if self.values is None:
            return 0
        return sum(1 for v in self.values if v is not None)

    def classify(self, value: float | None, better: str) -> str:
        if self.value is None:  # no seed gave a number: only "still none" is unchanged
            if value is None or not math.isfinite(value):
                return UNCHANGED
            return IMPROVED if better != EITHER else CHANGED
        v = _num(value, better)
        if self.lo <= v <= self.hi:
            return UNCHANGED
        if better == EITHER:
            return CHANGED
        worse = v > self.hi if better == LOWER else v < self.lo
        return REGRESSED if worse else IMPROVED

    def distance(self, value: float | None, better: str) -> float:
        """How far ``value`` lies from the mean in band half-widths, positive on the worse
        side (for a band without a better side: either way): 1 is the band's edge."""
        if self.value is None:
            return 0.0 if value is None or not math.isfinite(value) else math.inf
        v = _num(value, better)
        if math.isinf(v):
            return math.inf if (better != HIGHER) == (v > 0) or better == EITHER else -math.inf
        d = v - self.value
        half = (self.hi - self.value) if d >= 0 else (self.value - self.lo)
        x = d / half if half > 0 else (0.0 if d == 0 else math.copysign(math.inf, d))
        if better == EITHER:
            return abs(x)
        return -x if better == HIGHER else x

    def chance(self, value: float | None, better: str, n: int | None = None) -> float:
        """The probability that one more seed's value (or, for a band of a mean, the mean of
        as many seeds again) lies at least as far from the mean on the worse side (either
        side for a band without a better side): the prediction's t distribution with the
        band's floor as its least spread. ``n``: the seeds the band was drawn from (for a
        schema-1 band without its values)."""
        if self.value is None:
            return 1.0 if value is None or not math.isfinite(value) else 0.0
        v = _num(value, better)
        if math.isinf(v):
            worse = (v > 0) if better == LOWER else (v < 0) if better == HIGHER else True
            return 0.0 if worse else 1.0
        n = n or self.n
        tq = stats.t_quantile(0.5 + PREDICTION / 2, max(n - 1, 1))
        spread = max(_scale(n, self.of_mean) * self.sd if n > 1 else 0.0, self.floor / tq)
        if spread <= 0:
            return 1.0 if v == self.value else 0.0
        z = (v - self.value) / spread
        df = max(n - 1, 1)
        if better == EITHER:
            return min(1.0, 2.0 * stats.t_sf(abs(z), df))
        return stats.t_sf(z if better == LOWER else -z, df)


def _scale(n: int, of_mean: bool) -> float:
    """The spread of one more value's difference from the mean of n (sd sqrt(1 + 1/n)); of
    the mean of n more (a round-off change decorrelates the same seeds' values: sd
    sqrt(2/n))."""
    return math.sqrt(2.0 / n) if of_mean else math.sqrt(1.0 + 1.0 / n)


def floor_of(mean: float, unit: str) -> float:
    """The least half-width of a band around ``mean`` in ``unit``."""
    return max(UNIT_REL_FLOOR.get(unit, REL_FLOOR) * abs(mean), UNIT_FLOOR.get(unit, 0.0))


@dataclass(frozen=True)
class Record:
    """One criterion of one scenario in a baseline."""

    criterion: str
    metric: str
    window: tuple[float, float]
    params: Mapping[str, float]
    unit: str
    better: str
    outcome: str  # the criterion's outcome, the same for every seed
    band: Band
    # "value": the criterion's value; "mean": the mean of its per-seed values (a scenario
    # decided over its own seeds)
    stat: str = "value"
    # the mean over the seeds of what the metric says besides its value (the ISR's
    # instructions by step): where a flagged value moved (``where``)
    detail: Mapping[str, float] = field(default_factory=dict)

    def statistic(self, c: Mapping[str, Any]) -> float | None:
        """What of a run's criterion is compared with the band."""
        if self.stat != "mean":
            v = c.get("value")
            return None if v is None else float(v)
        vals = [x.get("value") for x in c.get("seeds") or []]
        if not vals:
            return None
        if any(v is None for v in vals):
            return None  # a seed without a number: the worst of its side
        return sum(float(v) for v in vals) / len(vals)

    def judged(self, got: float | None, seeds: int) -> dict[str, Any]:
        """The baseline entry of a criterion whose statistic is ``got``: its class against
        the band, its distance from the mean in band half-widths (positive: worse) and the
        chance of a move that far at one more seed."""
        b = self.band
        out: dict[str, Any] = {
            "class": b.classify(got, self.better), "value": b.value, "lo": b.lo, "hi": b.hi,
            "better": self.better, "seeds": seeds,
            "distance": _finite_or_none(b.distance(got, self.better)),
            "chance": b.chance(got, self.better, n=b.n or seeds),
        }
        if self.stat == "mean":
            out["mean"] = got
        return out

    def where(self, c: Mapping[str, Any]) -> str:
        """Where a run's value moved against the recorded one, by the metric's detail (the
        ISR's steps): the part that grew most, and any other that grew by at least half as
        much ('' without a detail on both sides)."""
        got = c.get("detail") or {}
        if not self.detail or not got:
            return ""
        moves = sorted(((float(got[k]) - v, k, v) for k, v in self.detail.items() if k in got),
                       reverse=self.better != HIGHER)
        if not moves:
            return ""
        top = moves[0][0]
        if top == 0:
            return ""
        parts = [f"{k} {v:.6g} -> {float(got[k]):.6g} ({d:+.6g})" for d, k, v in moves
                 if d * top > 0 and abs(d) >= abs(top) / 2]
        return "moved in " + ", ".join(parts)

    def matches(self, c: Mapping[str, Any]) -> str:
        """Why a criterion of a run is not this record's ('' when it is)."""
        if c.get("metric") != self.metric:
            return f"metric {c.get('metric')} (recorded: {self.metric})"
        w = c.get("window") or (None, None)
        if not _same(w[0], self.window[0]) or not _same(w[1], self.window[1]):
            return f"window {list(w)} (recorded: {list(self.window)})"
        if dict(c.get("params") or {}) != dict(self.params):
            return f"params {dict(c.get('params') or {})} (recorded: {dict(self.params)})"
        if better_side(c) != self.better:
            return f"better side {better_side(c)} (recorded: {self.better})"
        return ""


def _same(a: Any, b: Any) -> bool:
    try:
        return math.isclose(float(a), float(b), rel_tol=1e-9, abs_tol=1e-12)
    except (TypeError, ValueError):
        return False


@dataclass
class Entry:
    """A scenario run in a baseline: its set-up digest and its criteria."""

    key: str
    setup: str
    records: dict[str, Record] = field(default_factory=dict)


@dataclass
class Baseline:
    """One suite's baseline file."""

    suite: str
    seeds: tuple[int, ...]
    recorded: str
    source: dict[str, Any]
    entries: dict[str, Entry]
    path: Path | None = None

    # -- judging a run ------------------------------------------------------------------
    def judge(self, key: str, setup: str, seed: int | None,
              criteria: Iterable[dict[str, Any]], require: bool = False) -> dict[str, Any]:
        """Adds a ``baseline`` entry to each criterion of a run (result.json); returns the
        run's summary of them. Any seed is judged: the band describes one more seed's value,
        recorded or not. ``require``: a criterion without a line of its own fails
        (``missing``)."""
        entry = self.entries.get(key)
        why_stale = ""
        if entry is not None and entry.setup != setup:
            why_stale = ("the scenario's set-up (profile, overrides, drive, profiles, faults "
                         "or duration) changed since the baseline was recorded")
        counts = dict.fromkeys(CLASSES, 0)
        for c in criteria:
            rec = entry.records.get(str(c.get("name"))) if entry is not None else None
            if entry is None or rec is None:
                if require and entry is not None:
                    c["baseline"] = {"class": MISSING, "note": (
                        f"{_shown(self.path)} has no line for this criterion of {key}; record "
                        f"the baseline again (rig baseline record {self.suite})")}
                else:
                    c["baseline"] = {"class": NEW, "note": "no baseline"}
            elif why_stale or rec.matches(c):
                note = why_stale or f"the criterion changed: {rec.matches(c)}"
                c["baseline"] = {"class": STALE, "note": note + "; record the baseline again "
                                 f"(rig baseline record {self.suite})"}
            else:
                c["baseline"] = rec.judged(rec.statistic(c), len(self.seeds))
                if rec.stat == "mean":
                    c["baseline"].update(stat="mean", seeds=len(c.get("seeds") or []))
                where = rec.where(c) if c["baseline"]["class"] in (REGRESSED, CHANGED) else ""
                if where:
                    c["baseline"]["where"] = where
            counts[c["baseline"]["class"]] += 1
        return {
            "file": _shown(self.path), "suite": self.suite,
            "seeds": list(self.seeds), "recorded": self.recorded, "seed": seed,
            "counts": {k: v for k, v in counts.items() if v},
            "passed": not any(counts[k] for k in FAILING),
        }

    # -- the file -------------------------------------------------------------------------
    def dumps(self) -> str:
        """The file: a comment saying what it is, then one line per criterion (written with
        tomlkit, which keeps a comment and an inline table per line as a reviewer reads
        them)."""
        import tomlkit

        doc = tomlkit.document()
        for line in (
            f"The baseline of suite `{self.suite}`: every criterion's value over the plant's "
            f"noise seeds {_span(self.seeds)},",
            "the value at each seed (values) and its band (rig/regression/baseline.py: the "
            f"{PREDICTION:.0%}",
            f"prediction interval of one more seed, at least {REL_FLOOR:.0%} of the mean or "
            "the unit's resolution),",
            "widened to the seeds' range. Written by "
            f"`rig baseline record {self.suite}`; a change to it",
            "is a change of accepted behaviour: review it like code.",
        ):
            doc.add(tomlkit.comment(line))
        doc["schema"] = SCHEMA
        doc["suite"] = self.suite
        doc["seeds"] = list(self.seeds)
        doc["recorded"] = self.recorded
        doc["source"] = _inline_table(self.source)
        entries = tomlkit.table(is_super_table=True)
        for key in sorted(self.entries):
            e = self.entries[key]
            t = tomlkit.table()
            t["setup"] = e.setup
            for name, r in e.records.items():
                b = r.band
                row: dict[str, Any] = {
                    "metric": r.metric, "window": list(r.window), "unit": r.unit,
                    "better": r.better, "outcome": r.outcome, "value": _sig(b.value),
                    "lo": b.lo, "hi": b.hi, "sd": _sig(b.sd), "min": _sig(b.seeds_min),
                    "max": _sig(b.seeds_max),
                }
                if r.params:
                    row["params"] = dict(r.params)
                if r.stat != "value":
                    row["stat"] = r.stat
                if r.detail:
                    row["detail"] = {k: _sig(v) for k, v in r.detail.items()}
                row["values"] = [math.nan if v is None else v for v in (b.values or ())]
                t[name] = _inline_table(row)
            entries[key] = t
        doc["entries"] = entries
        return tomlkit.dumps(doc)

    @classmethod
    def loads(cls, text: str, path: Path | None = None) -> Baseline:
        """A baseline file, checked whole: a field missing or of the wrong type, a number
        out of reason, a band that does not hold its own recorded value or its seeds' values
        is a :class:`BaselineError` naming the file and line."""
        where = str(path) if path else "baseline"
        try:
            data = tomllib.loads(text)
        except (tomllib.TOMLDecodeError, ValueError, RecursionError) as exc:
            raise BaselineError(f"{where}: not TOML: {exc}") from exc
        if data.get("schema") not in SCHEMAS:
            raise BaselineError(f"{where}:{_line(text, ('schema',))}: schema "
                                f"{str(data.get('schema'))[:40]!r}, expected {SCHEMA!r}")
        check = _Checker(text, where)
        suite = check.string(data, ("suite",))
        seeds = check.seeds(data)
        source = data.get("source") or {}
        if not isinstance(source, dict):
            check.fail(("source",), "source is not a table")
        raw_entries = data.get("entries") or {}
        if not isinstance(raw_entries, dict):
            check.fail(("entries",), "entries is not a table")
        entries: dict[str, Entry] = {}
        for key, raw in raw_entries.items():
            if not isinstance(raw, dict):
                check.fail(("entries", key), f"entry {key!r} is not a table")
            e = Entry(key, check.string(raw, ("entries", key, "setup"), under=raw))
            for name, row in raw.items():
                if name == "setup":
                    continue
                e.records[name] = check.record(key, name, row, len(seeds),
                                               data.get("schema") == SCHEMA)
            entries[key] = e
        return cls(suite, seeds, str(data.get("recorded", "")), dict(source), entries, path)

    @classmethod
    def load(cls, path: Path) -> Baseline:
        try:
            return cls.loads(path.read_text(encoding="utf-8"), path)
        except OSError as exc:
            raise BaselineError(f"cannot read {path}: {exc.strerror or exc}") from exc


class _Checker:
    """Reads a baseline's fields with their types and reasons checked, naming file:line."""

    def __init__(self, text: str, where: str) -> None:
        self.text, self.where = text, where

    def fail(self, path: tuple[str | int, ...], what: str) -> NoReturn:
        raise BaselineError(f"{self.where}:{_line(self.text, path)}: {what}")

    def string(self, data: Mapping[str, Any], path: tuple[str, ...],
               under: Mapping[str, Any] | None = None) -> str:
        v = (under if under is not None else data).get(path[-1])
        if not isinstance(v, str):
            self.fail(path, f"{path[-1]} must be a string")
        return v

    def seeds(self, data: Mapping[str, Any]) -> tuple[int, ...]:
        v = data.get("seeds")
        if (not isinstance(v, list) or len(v) < MIN_SEEDS
                or not all(isinstance(x, int) and not isinstance(x, bool) and 0 <= x < 2**53
                           for x in v) or len(set(v)) != len(v)):
            self.fail(("seeds",), f"seeds must be a list of at least {MIN_SEEDS} distinct "
                      "seeds (integers)")
        return tuple(v)

    def number(self, row: Mapping[str, Any], path: tuple[str | int, ...], field: str,
               allow_nan: bool = False) -> float:
        v = row.get(field)
        if isinstance(v, bool) or not isinstance(v, int | float):
            self.fail((*path, field), f"{field} must be a number")
        x = float(v)
        if math.isnan(x) and allow_nan:
            return x
        if not math.isfinite(x) or abs(x) > 1e15:
            self.fail((*path, field), f"{field} = {str(v)[:30]} is not a finite number "
                      "of reasonable size")
        return x

    def record(self, key: str, name: str, row: Any, n_seeds: int, with_values: bool
               ) -> Record:
        path: tuple[str | int, ...] = ("entries", key, name)
        if not isinstance(row, dict):
            self.fail(path, f"criterion {name!r} is not a table")
        for f in ("metric", "unit", "better", "outcome"):
            if not isinstance(row.get(f), str):
                self.fail((*path, f), f"{f} must be a string")
        if row["better"] not in (LOWER, HIGHER, EITHER):
            self.fail((*path, "better"), f"better must be {LOWER}, {HIGHER} or {EITHER}")
        w = row.get("window")
        if (not isinstance(w, list) or len(w) != 2
                or not all(isinstance(x, int | float) and not isinstance(x, bool) for x in w)):
            self.fail((*path, "window"), "window must be two numbers")
        params = row.get("params") or {}
        if not isinstance(params, dict) or not all(
                isinstance(x, int | float) and not isinstance(x, bool) for x in params.values()):
            self.fail((*path, "params"), "params must be a table of numbers")
        stat = row.get("stat", "value")
        if stat not in ("value", "mean"):
            self.fail((*path, "stat"), "stat must be value or mean")
        value = self.number(row, path, "value", allow_nan=True)
        sd = self.number(row, path, "sd", allow_nan=True)
        lo = self.number(row, path, "lo", allow_nan=True)
        hi = self.number(row, path, "hi", allow_nan=True)
        vmin = self.number(row, path, "min", allow_nan=True)
        vmax = self.number(row, path, "max", allow_nan=True)
        values: tuple[float | None, ...] | None = None
        if with_values:
            raw = row.get("values")
            if not isinstance(raw, list) or not all(
                    isinstance(x, int | float) and not isinstance(x, bool) for x in raw):
                self.fail((*path, "values"), "values must be a list of numbers (nan: none)")
            if any(math.isinf(float(x)) or abs(float(x)) > 1e15 for x in raw):
                self.fail((*path, "values"), "values must be finite numbers or nan")
            values = tuple(None if math.isnan(float(x)) else float(x) for x in raw)
            if stat == "value" and len(values) != n_seeds:
                self.fail((*path, "values"), f"values has {len(values)} entries for "
                          f"{n_seeds} seeds")
        band = Band(_opt(value), 0.0 if math.isnan(sd) else sd, lo, hi, _opt(vmin),
                    _opt(vmax), values, floor_of(value if math.isfinite(value) else 0.0,
                                                 row["unit"]), stat == "mean")
        why = band_problem(band)
        if why:
            self.fail(path, f"criterion {name!r}: {why}; record the baseline again")
        detail = row.get("detail") or {}
        if not isinstance(detail, dict) or not all(
                isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x)
                for x in detail.values()):
            self.fail((*path, "detail"), "detail must be a table of finite numbers")
        return Record(name, row["metric"], (w[0], w[1]), dict(params), row["unit"],
                      row["better"], row["outcome"], band, stat,
                      {str(k): float(v) for k, v in detail.items()})


def band_problem(b: Band) -> str:
    """Why a band cannot judge anything ('' when it can): it must hold its own mean and,
    unless it is a band of a mean, every seed's value; its per-seed values must give its
    mean."""
    if b.value is None:
        if b.values and any(v is not None for v in b.values):
            return "value is nan but some seeds have a value"
        return ""
    if not (math.isfinite(b.lo) and math.isfinite(b.hi)) or b.lo > b.hi:
        return f"band {b.lo} .. {b.hi} is not an interval"
    if not b.lo <= b.value <= b.hi:
        return f"band {b.lo:.6g} .. {b.hi:.6g} does not hold its own value {b.value:.6g}"
    if b.sd < 0:
        return f"sd {b.sd} is negative"
    nums = [v for v in (b.values or ()) if v is not None]
    if nums:
        mean = sum(nums) / len(nums)
        if not math.isclose(mean, b.value, rel_tol=1e-4, abs_tol=1e-9 + 1e-4 * b.floor):
            return f"its values average {mean:.6g}, not its value {b.value:.6g}"
        if not b.of_mean and not all(b.lo <= v <= b.hi for v in nums):
            return "band does not hold every seed's value"
    return ""


def _line(text: str, path: tuple[str | int, ...]) -> int:
    """The line of ``path`` in a baseline's text (its nearest enclosing key's; 1 if none)."""
    for k in range(len(path), 0, -1):
        got = positions.locate(text, path[:k])
        if got is not None:
            return got
    return 1


def _inline_table(d: Mapping[str, Any]) -> Any:
    import tomlkit

    t = tomlkit.inline_table()
    for k, v in d.items():
        t[k] = _inline_table(v) if isinstance(v, Mapping) else v
    return t


def _shown(path: Path | None) -> str | None:
    """A baseline file as a reader finds it: relative to the checkout when inside it."""
    if path is None:
        return None
    try:
        return str(path.resolve().relative_to(BASELINE_DIR.parent.parent))
    except ValueError:
        return str(path)


def _finite_or_none(x: float) -> float | None:
    """A number for result.json (JSON has no infinity): None stands for beyond any band."""
    return x if math.isfinite(x) else None


def _opt(v: Any) -> float | None:
    return None if v is None or (isinstance(v, float) and math.isnan(v)) else float(v)


def _sig(v: float | None) -> float:
    return math.nan if v is None else float(f"{v:.6g}")


def _span(seeds: Sequence[int]) -> str:
    s = sorted(seeds)
    if s and s == list(range(s[0], s[-1] + 1)) and len(s) > 2:
        return f"{s[0]}-{s[-1]}"
    return ",".join(map(str, s))


# --------------------------------------------------------------------------------------
# Recording


@dataclass(frozen=True)
class SeedResult:
    """What a baseline needs of one run: its criteria (result.json's), or why it has none."""

    criteria: Sequence[Mapping[str, Any]]
    failure: str = ""


def build(suite: str, seeds: Sequence[int], scenarios: Sequence[Scenario],
          runs: Mapping[int, Sequence[SeedResult | None]], source: Mapping[str, Any],
          ) -> tuple[Baseline, list[str]]:
    """The baseline of a suite from its runs at every seed, and the problems that forbid
    accepting it: a criterion whose outcome differs between seeds (a verdict decided by the
    noise), one that fails or is not evaluated at every seed (a baseline holds accepted
    behaviour: fix it, or make it an XFAIL with its reason), a run without a result."""
    if len(seeds) < MIN_SEEDS:
        raise BaselineError(f"a baseline needs at least {MIN_SEEDS} seeds (got {len(seeds)})")
    problems: list[str] = []
    entries: dict[str, Entry] = {}
    for i, sc in enumerate(scenarios):
        key = entry_key(sc.name, sc.profile)
        per_seed: dict[int, SeedResult] = {}
        for seed in seeds:
            r = runs[seed][i]
            if r is None or r.failure:
                problems.append(f"{key} at seed {seed}: "
                                f"{r.failure if r is not None else 'no result'}")
            else:
                per_seed[seed] = r
        if len(per_seed) != len(seeds):
            continue
        entry = Entry(key, setup_digest(sc))
        for cr in sc.criteria:
            got = [next((c for c in per_seed[s].criteria if c.get("name") == cr.name), None)
                   for s in seeds]
            if any(c is None for c in got):
                problems.append(f"{key}: criterion {cr.name!r} missing at some seeds")
                continue
            outcomes = [str(c["outcome"]) for c in got if c is not None]
            if len(set(outcomes)) > 1:
                by: dict[str, list[int]] = {}
                for s, o in zip(seeds, outcomes, strict=True):
                    by.setdefault(o, []).append(s)
                problems.append(f"{key}: {cr.name!r} depends on the seed: " + "; ".join(
                    f"{o.upper()} at seeds {_span(ss)}" for o, ss in by.items()))
                continue
            if outcomes[0] in ("fail", "not_evaluated"):
                problems.append(f"{key}: {cr.name!r} is {outcomes[0].upper()} at every seed")
                continue
            first = got[0]
            assert first is not None
            unit = str(first.get("unit") or "")
            if sc.seeds:  # decided over its own seeds: the same run stands for every seed
                values = [x.get("value") for x in first.get("seeds") or []]
                band, stat = Band.of(values, unit, of_mean=True), "mean"
            else:
                values = [c.get("value") if c is not None else None for c in got]
                band, stat = Band.of(values, unit), "value"
            entry.records[cr.name] = Record(
                cr.name, cr.metric, (cr.window[0], cr.window[1]), dict(cr.params), unit,
                cr.side(), outcomes[0], band, stat,
                _mean_detail([c.get("detail") if c is not None else None for c in got]))
        entries[key] = entry
    return Baseline(suite, tuple(seeds), now(), dict(source), entries), problems


def _mean_detail(details: Sequence[Mapping[str, Any] | None]) -> dict[str, float]:
    """The mean per name of the seeds' details (empty unless every seed has one)."""
    if not details or any(not d for d in details):
        return {}
    names = [k for k in details[0] if all(k in d for d in details if d)]
    return {k: sum(float(d[k]) for d in details if d) / len(details) for k in names}


# --------------------------------------------------------------------------------------
# The baselines in the repository


def folder_of(folder: Path | None = None) -> Path:
    """The baselines' folder: the repository's, or ``$HIL_BASELINE_DIR``."""
    return folder or Path(os.environ.get("HIL_BASELINE_DIR") or BASELINE_DIR)


def files(folder: Path | None = None) -> list[Path]:
    folder = folder_of(folder)
    return sorted(folder.glob("*.toml")) if folder.is_dir() else []


def path_of(suite: str, folder: Path | None = None) -> Path:
    return folder_of(folder) / f"{suite}.toml"


@dataclass
class Index:
    """Every baseline file, looked up by scenario run (a scenario is in at most one)."""

    baselines: list[Baseline]
    by_key: dict[str, Baseline]

    @classmethod
    def load(cls, folder: Path | None = None) -> Index:
        baselines = [Baseline.load(p) for p in files(folder)]
        by_key: dict[str, Baseline] = {}
        for b in baselines:
            for key in b.entries:
                other = by_key.get(key)
                if other is not None:
                    raise BaselineError(
                        f"{key} has a baseline in both {other.path} and {b.path}: a scenario "
                        "run belongs to one suite's baseline")
                by_key[key] = b
        return cls(baselines, by_key)

    def for_key(self, key: str) -> Baseline | None:
        return self.by_key.get(key)


_cache: dict[Path, tuple[tuple[tuple[str, int], ...], Index]] = {}


def index(folder: Path | None = None) -> Index:
    """The baselines of ``folder`` (the repository's), read again only when a file changed."""
    folder = folder_of(folder)
    stamp = tuple((p.name, p.stat().st_mtime_ns) for p in files(folder))
    hit = _cache.get(folder)
    if hit is None or hit[0] != stamp:
        hit = (stamp, Index.load(folder))
        _cache[folder] = hit
    return hit[1]


def now() -> str:
    return dt.datetime.now(dt.UTC).isoformat(timespec="seconds")


MODES = ("auto", "require", "off")


def check_mode(mode: str) -> Index | None:
    """The baselines a run with ``--baseline MODE`` is judged against, read and checked
    before anything runs (a malformed file is a :class:`BaselineError` naming file and
    line): the repository's for ``auto`` and ``require``, the one file for a path, none for
    ``off``."""
    if mode == "off":
        return None
    if mode in MODES:
        return index()
    path = Path(mode)
    if not path.is_file():
        raise BaselineError(f"--baseline {mode}: no such file (auto, require, off or a "
                            "baseline file)")
    b = Baseline.load(path)
    return Index([b], dict.fromkeys(b.entries, b))


def judge_result(result: RunResult, sc: Scenario, mode: str, realtime: bool) -> None:
    """Each criterion's value of a run against the committed baseline (or, for ``mode`` a
    file, that file's), into ``result``: a regressed, changed, stale or missing one fails the
    run (until a confirmation over fresh seeds says otherwise: rig.regression.confirm); with
    ``mode`` "require" or a file, a run or criterion without a baseline fails too. Real-time
    runs are not compared (their timing is the wall clock's, not the seed's)."""
    if mode == "off":
        return
    key = entry_key(sc.name, sc.profile)
    if realtime:
        result.baseline = {"skipped": "real-time runs are not compared with the baseline"}
        return
    require = mode != "auto"
    try:
        idx = check_mode(mode)
        found = idx.for_key(key) if idx is not None else None
    except BaselineError as exc:
        result.baseline = {"passed": False, "error": str(exc)}
        result.passed = False
        result.status = "failed" if result.status == "passed" else result.status
        return
    if found is None:
        where = f"in {mode}" if mode not in MODES else "in rig/baselines"
        result.baseline = {"passed": not require, "missing": key,
                           "note": f"no baseline {where} holds {key}"}
    else:
        seed = sc.seed if sc.seed is not None else (None if sc.seeds else 1)
        result.baseline = found.judge(key, setup_digest(sc), seed, result.criteria,
                                      require=require)
    if not result.baseline["passed"]:
        result.passed = False
        if result.status == "passed":
            result.status = "failed"
