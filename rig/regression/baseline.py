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

A regressed, changed or stale criterion fails the run (exit 1) even inside its limit, and an
XFAIL is held to its measured value the same way: it fails when it gets worse.

The band. Over N seeds (N >= 5) with mean m and sample standard deviation s, the band is
m +- max(t(0.995, N-1) sqrt(1 + 1/N) s, floor), widened to hold every seed's value: the 99 %
prediction interval of one more seed's value (3.7 s for N = 8), so a seed outside the
recorded ones lands outside the band about once in a hundred criteria while a bug that moves
a value by several times its seed spread does not get in. The floor, max(1 % of |m|, the
unit's resolution), keeps a band for values the noise barely moves (counters, fault codes,
a speed the drive reaches whatever the noise) from catching round-off. The seed also
dithers the start angle by a thousandth of a degree (Scenario.with_seed), so the noise-free
``ideal`` profile gets the spread its deterministic but sensitive closed loop has. A value
without a number (never detected, no data) counts as the worst value of its side.
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
from typing import Any

from rig.regression import stats
from rig.results.result import RunResult
from rig.scenario import SEED_KEY, Scenario
from rig.scenario.model import side_of

BASELINE_DIR = Path(__file__).resolve().parents[1] / "baselines"
SCHEMA = "hil-baseline/1"
MIN_SEEDS = 5
PREDICTION = 0.99  # two-sided level of the prediction interval of one more seed
REL_FLOOR = 0.01
# the smallest band half-width per unit: the resolution a value is meaningful to
UNIT_FLOOR = {
    "deg": 0.01, "r/min": 0.01, "%": 0.01, "A": 1e-3, "N*m": 1e-3, "V": 0.01, "mH": 1e-3,
    "Wb": 1e-5, "s": 1e-4, "periods": 1.0,
}

UNCHANGED, IMPROVED, REGRESSED, CHANGED, STALE, NEW = (
    "unchanged", "improved", "regressed", "changed", "stale", "new")
CLASSES = (UNCHANGED, IMPROVED, REGRESSED, CHANGED, STALE, NEW)
# classes that fail a run
FAILING = (REGRESSED, CHANGED, STALE)

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
    overrides, drive, speed and load profiles, faults, duration. A change here makes the
    scenario's baseline stale."""
    overrides = {k: v for k, v in sorted(sc.overrides.items()) if k != SEED_KEY}
    parts = (sc.profile, overrides, sorted(sc.firmware.items()), sc.ctrl_mode, sc.fw_mode,
             sc.enable_at, sc.iq_ref, sc.i_max, sc.speed_max, sc.step_accel,
             sc.initial_theta_deg, sc.initial_speed_rpm, sc.speed, sc.load, sc.faults,
             sc.duration, sc.seeds)
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
    """The accepted value of one criterion and its tolerance band."""

    value: float | None  # the mean over the seeds (None: no seed gave a number)
    sd: float
    lo: float
    hi: float
    seeds_min: float | None
    seeds_max: float | None

    @classmethod
    def of(cls, values: Sequence[float | None], unit: str, of_mean: bool = False) -> Band:
        """The band of one more value like ``values`` (one per seed), or with ``of_mean``
        of the mean of as many values again drawn on the same seeds (a scenario decided
        over its own seeds: its value is the worst of a noisy sample, the mean of that
        sample is what can be compared)."""
        nums = [float(v) for v in values if v is not None and math.isfinite(v)]
        if not nums:
            return cls(None, 0.0, math.nan, math.nan, None, None)
        n = len(nums)
        m = sum(nums) / n
        sd = math.sqrt(sum((v - m) ** 2 for v in nums) / (n - 1)) if n > 1 else 0.0
        floor = max(REL_FLOOR * abs(m), UNIT_FLOOR.get(unit, 0.0))
        # the difference of one more value from the mean: sd sqrt(1 + 1/n); of the mean of n
        # more (a round-off change decorrelates the same seeds' values): sd sqrt(2/n)
        scale = math.sqrt(2.0 / n) if of_mean else math.sqrt(1.0 + 1.0 / n)
        spread = stats.t_quantile(0.5 + PREDICTION / 2, n - 1) * scale * sd if n > 1 else 0.0
        half = max(spread, floor)
        lo, hi = m - half, m + half
        if not of_mean:
            lo, hi = min(lo, min(nums)), max(hi, max(nums))
        return cls(m, sd, _round_out(lo, up=False), _round_out(hi, up=True), min(nums),
                   max(nums))

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
              criteria: Iterable[dict[str, Any]]) -> dict[str, Any]:
        """Adds a ``baseline`` entry to each criterion of a run (result.json); returns the
        run's summary of them."""
        entry = self.entries.get(key)
        why_stale = ""
        if entry is None:
            why_stale = ""
        elif entry.setup != setup:
            why_stale = ("the scenario's set-up (profile, overrides, drive, profiles, faults "
                         "or duration) changed since the baseline was recorded")
        elif seed is not None and seed not in self.seeds:
            why_stale = (f"seed {seed} is not one of the recorded seeds "
                         f"{_span(self.seeds)}")
        counts = dict.fromkeys(CLASSES, 0)
        for c in criteria:
            rec = entry.records.get(str(c.get("name"))) if entry is not None else None
            if entry is None or rec is None:
                cls, note = NEW, "no baseline"
                c["baseline"] = {"class": cls, "note": note}
            elif why_stale or rec.matches(c):
                note = why_stale or f"the criterion changed: {rec.matches(c)}"
                c["baseline"] = {"class": STALE, "note": note + "; record the baseline again "
                                 f"(rig baseline record {self.suite})"}
            else:
                got = rec.statistic(c)
                cls = rec.band.classify(got, rec.better)
                c["baseline"] = {
                    "class": cls, "value": rec.band.value, "lo": rec.band.lo,
                    "hi": rec.band.hi, "better": rec.better, "seeds": len(self.seeds),
                }
                if rec.stat == "mean":
                    c["baseline"].update(stat="mean", mean=got,
                                         seeds=len(c.get("seeds") or []))
            counts[c["baseline"]["class"]] += 1
        return {
            "file": _shown(self.path), "suite": self.suite,
            "seeds": list(self.seeds), "recorded": self.recorded,
            "counts": {k: v for k, v in counts.items() if v},
            "passed": not any(counts[k] for k in FAILING),
        }

    # -- the file -------------------------------------------------------------------------
    def dumps(self) -> str:
        lines = [
            f"# The baseline of suite `{self.suite}`: every criterion's value over the plant's",
            f"# noise seeds {_span(self.seeds)} and its band (rig/regression/baseline.py: the "
            f"{PREDICTION:.0%} prediction interval of one",
            f"# more seed, at least {REL_FLOOR:.0%} of the mean or the unit's resolution), "
            "widened to the seeds' range. Written by",
            f"# `rig baseline record {self.suite}`; a change to it is a change of accepted "
            "behaviour:",
            "# review it like code.",
            f'schema = "{SCHEMA}"',
            f"suite = {_toml(self.suite)}",
            f"seeds = {_toml(list(self.seeds))}",
            f"recorded = {_toml(self.recorded)}",
            f"source = {_inline(self.source)}",
        ]
        for key in sorted(self.entries):
            e = self.entries[key]
            lines += ["", f"[entries.{_toml(key)}]", f"setup = {_toml(e.setup)}"]
            for name, r in e.records.items():
                b = r.band
                row = {
                    "metric": r.metric, "window": list(r.window), "unit": r.unit,
                    "better": r.better, "outcome": r.outcome, "value": _sig(b.value),
                    "lo": b.lo, "hi": b.hi, "sd": _sig(b.sd), "min": _sig(b.seeds_min),
                    "max": _sig(b.seeds_max),
                }
                if r.params:
                    row["params"] = dict(r.params)
                if r.stat != "value":
                    row["stat"] = r.stat
                lines.append(f"{_toml(name)} = {_inline(row)}")
        return "\n".join(lines) + "\n"

    @classmethod
    def loads(cls, text: str, path: Path | None = None) -> Baseline:
        where = str(path) if path else "baseline"
        try:
            data = tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            raise BaselineError(f"{where}: {exc}") from exc
        if data.get("schema") != SCHEMA:
            raise BaselineError(f"{where}: schema {data.get('schema')!r}, expected {SCHEMA!r}")
        entries: dict[str, Entry] = {}
        try:
            for key, raw in (data.get("entries") or {}).items():
                e = Entry(key, str(raw.get("setup", "")))
                for name, row in raw.items():
                    if name == "setup":
                        continue
                    band = Band(_opt(row["value"]), float(row["sd"]), float(row["lo"]),
                                float(row["hi"]), _opt(row["min"]), _opt(row["max"]))
                    e.records[name] = Record(
                        name, str(row["metric"]), (row["window"][0], row["window"][1]),
                        dict(row.get("params") or {}), str(row["unit"]), str(row["better"]),
                        str(row["outcome"]), band, str(row.get("stat", "value")))
                entries[key] = e
            return cls(str(data["suite"]), tuple(int(s) for s in data["seeds"]),
                       str(data.get("recorded", "")), dict(data.get("source") or {}),
                       entries, path)
        except (KeyError, TypeError, ValueError, IndexError) as exc:
            raise BaselineError(f"{where}: malformed entry ({exc!r})") from exc

    @classmethod
    def load(cls, path: Path) -> Baseline:
        try:
            return cls.loads(path.read_text(encoding="utf-8"), path)
        except OSError as exc:
            raise BaselineError(f"cannot read {path}: {exc.strerror or exc}") from exc


def _shown(path: Path | None) -> str | None:
    """A baseline file as a reader finds it: relative to the checkout when inside it."""
    if path is None:
        return None
    try:
        return str(path.resolve().relative_to(BASELINE_DIR.parent.parent))
    except ValueError:
        return str(path)


def _opt(v: Any) -> float | None:
    return None if v is None or (isinstance(v, float) and math.isnan(v)) else float(v)


def _sig(v: float | None) -> float:
    return math.nan if v is None else float(f"{v:.6g}")


def _span(seeds: Sequence[int]) -> str:
    s = sorted(seeds)
    if s and s == list(range(s[0], s[-1] + 1)) and len(s) > 2:
        return f"{s[0]}-{s[-1]}"
    return ",".join(map(str, s))


def _toml(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, list | tuple):
        return "[" + ", ".join(_toml(x) for x in v) + "]"
    if isinstance(v, Mapping):
        return _inline(v)
    if v is None:
        return "nan"
    raise TypeError(f"cannot write {type(v).__name__} to a baseline")


def _inline(d: Mapping[str, Any]) -> str:
    return "{ " + ", ".join(f"{_key(k)} = {_toml(v)}" for k, v in d.items()) + " }"


def _key(k: str) -> str:
    return k if k.replace("_", "").replace("-", "").isalnum() else _toml(k)


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
                cr.side(), outcomes[0], band, stat)
        entries[key] = entry
    return Baseline(suite, tuple(seeds), now(), dict(source), entries), problems


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


def judge_result(result: RunResult, sc: Scenario, mode: str, realtime: bool) -> None:
    """Each criterion's value of a run against the committed baseline, into ``result``: a
    regressed, changed or stale one fails the run; with ``mode`` "require" a run without a
    baseline fails too. Real-time runs are not compared (their timing is the wall clock's,
    not the seed's)."""
    if mode == "off":
        return
    key = entry_key(sc.name, sc.profile)
    if realtime:
        result.baseline = {"skipped": "real-time runs are not compared with the baseline"}
        return
    try:
        found = index().for_key(key)
    except BaselineError as exc:
        result.baseline = {"passed": False, "error": str(exc)}
        result.passed = False
        result.status = "failed" if result.status == "passed" else result.status
        return
    if found is None:
        result.baseline = {"passed": mode != "require", "missing": key,
                           "note": f"no baseline holds {key}"}
    else:
        result.baseline = found.judge(key, setup_digest(sc), sc.seed, result.criteria)
    if not result.baseline["passed"]:
        result.passed = False
        if result.status == "passed":
            result.status = "failed"
