"""Scenarios as data: one TOML file per scenario, suites as files listing scenarios.

A scenario names a fidelity profile (plus overrides), the drive modes, a speed profile (a
sequence of segments), a load profile (events at absolute times), faults (``[[faults]]``,
``rig.faults``), the initial rotor state, the duration and the pass criteria. ``load()``
validates a file and reports every schema error with the file, the line and the field
(``file:line: field: message``); the CLI exits 2 on them. The wire enumerations (control
modes, flux-weakening modes, load modes) come from the DBC choices, not from this module.

Times are simulated seconds from the start of PWM period 0 and are rounded to the PWM
period (100 µs) when the scenario is planned.
"""

from __future__ import annotations

import math
import re
import tomllib
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field, replace
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from rig import _paths, faults, metrics, params, plant_schema, profiles, protocols

SCENARIO_DIR = Path(__file__).resolve().parent / "scenarios"
SUITE_DIR = SCENARIO_DIR / "suites"
PROFILES = ("ideal", "paper", "harsh")

Path_ = tuple[str | int, ...]


# --------------------------------------------------------------------------------------
# Errors with positions


@dataclass(frozen=True)
class Issue:
    file: str
    line: int | None
    field: str
    message: str

    def __str__(self) -> str:
        where = f"{self.file}:{self.line}" if self.line else self.file
        if self.field:
            return f"{where}: {self.field}: {self.message}"
        return f"{where}: {self.message}"


class ScenarioError(ValueError):
    """One or more schema errors; ``str()`` gives one ``file:line: field: message`` per line."""

    def __init__(self, issues: Sequence[Issue]) -> None:
        self.issues = list(issues)
        super().__init__("\n".join(str(i) for i in self.issues))


def field_name(path: Path_) -> str:
    out = ""
    for part in path:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += f".{part}" if out else part
    return out


# --------------------------------------------------------------------------------------
# Where is a key? tomllib gives values without positions; a small token scanner maps every
# key path (and every array element) of a syntactically valid TOML text to its line.

_PUNCT = set("[]{}=,")
_ATOM_END = set(" \t\r\n[]{}=,#\"'")


def _tokens(text: str) -> Iterator[tuple[str, str, int]]:
    """(kind, value, line): kind is 'punct', 'str', 'atom' or 'nl'."""
    i, line, n = 0, 1, len(text)
    while i < n:
        c = text[i]
        if c == "\n":
            yield "nl", c, line
            line += 1
            i += 1
        elif c in " \t\r":
            i += 1
        elif c == "#":
            while i < n and text[i] != "\n":
                i += 1
        elif c in _PUNCT:
            yield "punct", c, line
            i += 1
        elif c in "\"'":
            start_line = line
            triple = text.startswith(c * 3, i)
            quote = c * 3 if triple else c
            j = i + len(quote)
            buf: list[str] = []
            while j < n and not text.startswith(quote, j):
                if text[j] == "\\" and c == '"' and j + 1 < n:
                    buf.append(text[j : j + 2])
                    line += text[j : j + 2].count("\n")
                    j += 2
                    continue
                if text[j] == "\n":
                    line += 1
                buf.append(text[j])
                j += 1
            if triple:
                while text.startswith(c, j + 3):  # up to two extra quotes belong to the string
                    j += 1
            i = j + len(quote)
            yield "str", "".join(buf), start_line
        else:
            j = i
            while j < n and text[j] not in _ATOM_END:
                j += 1
            yield "atom", text[i:j], line
            i = j


class _Locator:
    def __init__(self, text: str) -> None:
        self.lines: dict[Path_, int] = {}
        self._toks = list(_tokens(text))
        self._i = 0
        self._aot: dict[Path_, int] = {}
        try:
            self._document()
        except IndexError:
            pass

    def _peek(self, k: int = 0) -> tuple[str, str, int]:
        j = self._i + k
        return self._toks[j] if j < len(self._toks) else ("eof", "", 0)

    def _next(self) -> tuple[str, str, int]:
        tok = self._peek()
        self._i += 1
        return tok

    def _skip_nl(self) -> None:
        while self._peek()[0] == "nl":
            self._i += 1

    def _key(self) -> list[str]:
        parts: list[str] = []
        while True:
            kind, val, _ = self._peek()
            if kind == "str":
                parts.append(val)
            elif kind == "atom":
                parts.extend(p for p in val.split(".") if p)
            else:
                return parts
            self._i += 1

    def _resolve(self, parts: Sequence[str]) -> Path_:
        out: list[str | int] = []
        for p in parts:
            out.append(p)
            key = tuple(out)
            if key in self._aot:
                out.append(self._aot[key] - 1)
        return tuple(out)

    def _document(self) -> None:
        header: Path_ = ()
        while self._peek()[0] != "eof":
            self._skip_nl()
            kind, val, line = self._peek()
            if kind == "eof":
                break
            if kind == "punct" and val == "[":
                self._i += 1
                is_aot = self._peek()[0] == "punct" and self._peek()[1] == "["
                if is_aot:
                    self._i += 1
                parts = self._key()
                while self._peek()[0] == "punct" and self._peek()[1] == "]":
                    self._i += 1
                if is_aot:
                    base = (*self._resolve(parts[:-1]), parts[-1])
                    idx = self._aot.get(base, 0)
                    self._aot[base] = idx + 1
                    header = (*base, idx)
                    self.lines.setdefault(base, line)
                else:
                    header = self._resolve(parts)
                self.lines[header] = line
                continue
            if kind in ("atom", "str"):
                parts = self._key()
                path = header + tuple(parts)
                self.lines.setdefault(path, line)
                if self._peek()[1] == "=":
                    self._i += 1
                    self._value(path)
                    continue
            # anything unexpected: skip to the end of the line
            while self._peek()[0] not in ("nl", "eof"):
                self._i += 1

    def _value(self, path: Path_) -> None:
        self._skip_nl()
        kind, val, line = self._peek()
        if kind == "punct" and val == "[":
            self._i += 1
            idx = 0
            while True:
                self._skip_nl()
                kind, val, line = self._peek()
                if kind == "eof" or (kind == "punct" and val == "]"):
                    self._i += 1
                    return
                if kind == "punct" and val == ",":
                    self._i += 1
                    continue
                self.lines.setdefault((*path, idx), line)
                self._value((*path, idx))
                idx += 1
        elif kind == "punct" and val == "{":
            self._i += 1
            while True:
                self._skip_nl()
                kind, val, line = self._peek()
                if kind == "eof" or (kind == "punct" and val == "}"):
                    self._i += 1
                    return
                if kind == "punct" and val == ",":
                    self._i += 1
                    continue
                parts = self._key()
                if not parts:
                    self._i += 1
                    continue
                sub = path + tuple(parts)
                self.lines.setdefault(sub, line)
                if self._peek()[1] == "=":
                    self._i += 1
                    self._value(sub)
        else:
            self._i += 1


def locate(text: str, path: Path_) -> int | None:
    """Line (1-based) of the key or element at ``path``, else of its nearest located parent."""
    lines = _locator(text).lines
    p = tuple(path)
    while p:
        if p in lines:
            return lines[p]
        p = p[:-1]
    return None


@cache
def _locator(text: str) -> _Locator:
    return _Locator(text)


# --------------------------------------------------------------------------------------
# The model


@dataclass(frozen=True)
class SpeedSegment:
    kind: str
    duration: float
    to: float | None = None
    peak: float | None = None
    rise: float = 0.0
    hold: float = 0.0
    fall: float = 0.0
    dwell: float = 0.0
    repeat: int = 1


@dataclass(frozen=True)
class SpeedCommand:
    """At time ``t`` command speed_ref ``target`` with acceleration limit ``accel`` (r/min/s)."""

    t: float
    target: float
    accel: float


@dataclass(frozen=True)
class LoadEvent:
    at: float
    kind: str  # step | ramp | off | speed_hold
    torque: float = 0.0
    duration: float = 0.0
    speed: float = 0.0
    k_speed: float = 0.0


@dataclass(frozen=True)
class LoadCommand:
    """At time ``t`` set the load machine (mode name as in the DBC, lower case)."""

    t: float
    mode: str
    torque: float = 0.0
    speed: float = 0.0
    k_speed: float = 0.0


@dataclass(frozen=True)
class Criterion:
    name: str
    metric: str
    window: tuple[float, float]
    limit: float
    comparison: str = "<="
    params: Mapping[str, float] = field(default_factory=dict)
    # fidelity profiles the criterion applies on (empty: every profile)
    profiles: tuple[str, ...] = ()
    # known failure: the reason with the measured value; reported XFAIL (XPASS if it passes)
    xfail: str = ""

    def applies_to(self, profile: str) -> bool:
        return not self.profiles or profile in self.profiles


@dataclass(frozen=True)
class Scenario:
    name: str
    file: Path
    description: str
    profile: str
    duration: float
    figure: str = ""
    tags: tuple[str, ...] = ()
    overrides: Mapping[str, float | int | str | bool] = field(default_factory=dict)
    firmware: Mapping[str, float | int | str | bool] = field(default_factory=dict)
    ctrl_mode: str = "speed"
    fw_mode: str = "realtime"
    enable_at: float = 0.0
    iq_ref: float = 0.0
    i_max: float = 3.0
    speed_max: float = 3300.0
    step_accel: float = 0.0  # 0: the DBC maximum of accel_max
    initial_theta_deg: float = 0.0
    initial_speed_rpm: float = 0.0
    speed: tuple[SpeedSegment, ...] = ()
    load: tuple[LoadEvent, ...] = ()
    faults: tuple[faults.Fault, ...] = ()
    criteria: tuple[Criterion, ...] = ()
    grant_max_s: float = 0.1
    timeout_s: float = 0.0  # 0: derived from the duration
    ready_timeout_s: float = 10.0
    realtime_ok: bool = True

    def with_profile(self, profile: str) -> Scenario:
        """The same scenario on another fidelity profile, named ``<name>@<profile>``; only
        the criteria that apply on that profile are kept."""
        if profile not in PROFILES:
            raise ValueError(f"unknown profile {profile!r} (one of: {', '.join(PROFILES)})")
        if self.overrides and profile != self.profile:
            try:
                text = read_text(self.file)
            except OSError:
                text = ""
            c = _Checker(self.file, text)
            _check_overrides(c, profile, self.overrides)
            if c.issues:
                raise ScenarioError(c.issues)
        if self.faults and profile != self.profile:
            try:
                text = read_text(self.file)
            except OSError:
                text = ""
            c = _Checker(self.file, text)
            _check_stuck_codes(c, profile, self.overrides, self.faults)
            if c.issues:
                raise ScenarioError(c.issues)
        base = self.name.split("@", 1)[0]
        crits = tuple(c for c in self.criteria if c.applies_to(profile))
        return replace(self, name=f"{base}@{profile}", profile=profile, criteria=crits)

    # -- derived profiles ------------------------------------------------------------
    def speed_commands(self, step_accel: float) -> list[SpeedCommand]:
        """The commands the speed profile expands to (targets and acceleration limits)."""
        out: list[SpeedCommand] = []
        t, cur = 0.0, self.initial_speed_rpm
        accel_step = self.step_accel or step_accel

        def ramp(to: float, dur: float) -> None:
            nonlocal t, cur
            if dur <= 0:
                out.append(SpeedCommand(t, to, accel_step))
            else:
                out.append(SpeedCommand(t, to, abs(to - cur) / dur if to != cur else accel_step))
            cur = to
            t += max(dur, 0.0)

        for seg in self.speed:
            if seg.kind == "hold":
                t += seg.duration
            elif seg.kind == "step":
                assert seg.to is not None
                out.append(SpeedCommand(t, seg.to, accel_step))
                cur = seg.to
                t += seg.duration
            elif seg.kind in ("ramp", "reversal"):
                assert seg.to is not None
                ramp(seg.to, seg.duration)
            elif seg.kind in ("trapezoid", "triangle"):
                assert seg.peak is not None
                base = cur
                for _ in range(seg.repeat):
                    ramp(seg.peak, seg.rise)
                    t += seg.hold
                    ramp(base, seg.fall)
                    t += seg.dwell
        return out

    def speed_reference(self, t: npt.ArrayLike, step_accel: float) -> npt.NDArray[np.float64]:
        """The ramped speed reference the firmware follows (rate limiter of the commands)."""
        knots_t, knots_v = [0.0], [self.initial_speed_rpm]
        v = self.initial_speed_rpm
        cmds = self.speed_commands(step_accel)
        for k, cmd in enumerate(cmds):
            # the value reached at cmd.t under the previous command is the last knot
            t_next = cmds[k + 1].t if k + 1 < len(cmds) else math.inf
            if cmd.t > knots_t[-1]:
                knots_t.append(cmd.t)
                knots_v.append(v)
            if cmd.accel <= 0 or cmd.target == v:
                continue
            t_reach = cmd.t + abs(cmd.target - v) / cmd.accel
            if t_reach <= t_next:
                knots_t.append(t_reach)
                knots_v.append(cmd.target)
                v = cmd.target
            else:
                v = v + math.copysign(cmd.accel * (t_next - cmd.t), cmd.target - v)
                knots_t.append(t_next)
                knots_v.append(v)
        tt = np.asarray(t, dtype=np.float64)
        return np.interp(tt, np.asarray(knots_t), np.asarray(knots_v))

    def load_commands(self, resolution_s: float = 1e-3) -> list[LoadCommand]:
        """Load machine commands; a torque ramp becomes steps of ``resolution_s``."""
        out: list[LoadCommand] = [LoadCommand(0.0, "torque")]
        torque = 0.0
        k_speed = 0.0
        for ev in sorted(self.load, key=lambda e: e.at):
            if ev.kind == "step":
                k_speed = ev.k_speed
                out.append(LoadCommand(ev.at, "torque", ev.torque, 0.0, k_speed))
                torque = ev.torque
            elif ev.kind == "ramp":
                k_speed = ev.k_speed
                n = max(1, round(ev.duration / resolution_s))
                for j in range(n):
                    frac = (j + 0.5) / n
                    out.append(
                        LoadCommand(ev.at + j * ev.duration / n, "torque",
                                    torque + (ev.torque - torque) * frac, 0.0, k_speed)
                    )
                out.append(LoadCommand(ev.at + ev.duration, "torque", ev.torque, 0.0, k_speed))
                torque = ev.torque
            elif ev.kind == "off":
                out.append(LoadCommand(ev.at, "off"))
            elif ev.kind == "speed_hold":
                out.append(LoadCommand(ev.at, "speed_hold", 0.0, ev.speed, 0.0))
        return out

    def breakpoints(self, step_accel: float) -> list[float]:
        """Times at which a command changes (grants end exactly there)."""
        ts = {0.0, self.enable_at}
        ts.update(c.t for c in self.speed_commands(step_accel))
        ts.update(c.t for c in self.load_commands())
        for f in self.faults:
            ts.add(f.at)
            if f.duration is not None:
                ts.add(f.at + f.duration)
        return sorted(t for t in ts if 0.0 <= t < self.duration)


@dataclass(frozen=True)
class Comparison:
    """A suite-level criterion between two runs of the suite: the value of the criterion
    ``criterion`` in run ``a`` must stand in ``relation`` to its value in run ``b`` (for
    example Fig. 9: the real-time MTPA drops less speed than the conventional one)."""

    name: str
    criterion: str
    a: str
    b: str
    relation: str = "<"
    xfail: str = ""


@dataclass(frozen=True)
class Suite:
    name: str
    file: Path
    description: str
    scenarios: tuple[Scenario, ...]
    comparisons: tuple[Comparison, ...] = ()


# --------------------------------------------------------------------------------------
# Validation


SEGMENT_KINDS = ("hold", "step", "ramp", "reversal", "trapezoid", "triangle")
LOAD_KINDS = ("step", "ramp", "off", "speed_hold")
_NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]*$")


class _Checker:
    def __init__(self, file: Path, text: str) -> None:
        self.file = file
        self.text = text
        self.issues: list[Issue] = []

    def err(self, path: Path_, message: str) -> None:
        line = locate(self.text, path)
        self.issues.append(Issue(str(self.file), line, field_name(path), message))

    def table(self, data: Any, path: Path_, allowed: Iterable[str]) -> dict[str, Any]:
        if not isinstance(data, dict):
            self.err(path, f"must be a table, not {type(data).__name__}")
            return {}
        allowed = set(allowed)
        for key in data:
            if key not in allowed:
                self.err(
                    (*path, key),
                    f"unknown field (allowed here: {', '.join(sorted(allowed))})",
                )
        return data

    def number(
        self,
        data: Mapping[str, Any],
        path: Path_,
        key: str,
        default: float | None = None,
        *,
        minimum: float | None = None,
        maximum: float | None = None,
        positive: bool = False,
    ) -> float:
        p = (*path, key)
        if key not in data:
            if default is None:
                self.err(p, "required number is missing")
                return 0.0
            return default
        v = data[key]
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
            self.err(p, f"must be a finite number, not {v!r}")
            return default if default is not None else 0.0
        if positive and v <= 0:
            self.err(p, f"must be > 0, not {v!r}")
        if minimum is not None and v < minimum:
            self.err(p, f"must be >= {minimum:g}, not {v!r}")
        if maximum is not None and v > maximum:
            self.err(p, f"must be <= {maximum:g}, not {v!r}")
        return float(v)

    def string(
        self,
        data: Mapping[str, Any],
        path: Path_,
        key: str,
        default: str | None = None,
        choices: Iterable[str] | None = None,
    ) -> str:
        p = (*path, key)
        if key not in data:
            if default is None:
                self.err(p, "required string is missing")
                return ""
            return default
        v = data[key]
        if not isinstance(v, str):
            self.err(p, f"must be a string, not {v!r}")
            return default or ""
        if choices is not None:
            options = list(choices)
            if v.lower() not in options:
                self.err(p, f"{v!r} is not one of: {', '.join(options)}")
                return default or ""
            return v.lower()
        return v


# Upper bounds of the run's own numbers: a duration that would make the grant plan and the
# traces unbounded (1e7 s: MemoryError), and waits no run needs.
MAX_DURATION_S = 3600.0
MAX_TIMEOUT_S = 86400.0
MAX_READY_TIMEOUT_S = 600.0


def _key_path(section: str, key: str, text: str) -> Path_:
    """Where a flattened key of a table is: a quoted dotted key, or nested tables."""
    quoted: Path_ = (section, key)
    return quoted if locate(text, quoted) is not None else (section, *key.split("."))


def _check_overrides(c: _Checker, profile: str, overrides: Mapping[str, Any]) -> None:
    """The plant's own loader judges the overrides on the profile (rig.plant_schema)."""
    if not overrides or not plant_schema.available():
        return  # not built: plant_rt reports it at start (exit 2, named field)
    try:
        path = _paths.data_dir("profiles") / f"{profile}.toml"
    except FileNotFoundError:
        return
    for key, why in plant_schema.check(path, overrides).items():
        c.err(_key_path("overrides", key, c.text) if key else ("overrides",),
              why if key else f"on profile {profile!r}: {why}")


def _check_firmware(c: _Checker, firmware: Mapping[str, Any]) -> None:
    """Firmware parameters by name, in the ranges of protocols/parameters.csv."""
    if not firmware:
        return
    table = params.table()
    for key, value in firmware.items():
        where = _key_path("firmware", key, c.text)
        try:
            info = table.lookup(key)
        except params.ParamError:
            c.err(where, "unknown parameter (rig param list, protocols/parameters.csv)")
            continue
        if isinstance(value, bool) or not isinstance(value, int | float):
            c.err(where, f"must be a number, not {value!r}")
            continue
        problem = info.problem(float(value))
        if problem is not None:
            c.err(where, problem)


TOP_KEYS = (
    "name", "description", "profile", "duration", "figure", "tags", "overrides", "firmware",
    "drive", "limits", "initial", "speed", "load", "faults", "criteria", "run",
)


def _check_stuck_codes(c: _Checker, profile: str, overrides: Mapping[str, Any],
                       events: Sequence[faults.Fault]) -> None:
    """A stuck converter's code must be one the converter has, on this profile."""
    bits = faults.adc_bits_of(profiles.profile_values(profile, overrides))
    for i, f in enumerate(events):
        if f.kind == "adc_stuck" and f.channel in bits:
            top = (1 << bits[f.channel]) - 1
            if f.value > top:
                c.err(("faults", i, "code"), f"code {f.value:g} is beyond the {f.channel} "
                      f"converter of profile {profile!r} (0 .. {top})")


def _segment(c: _Checker, raw: Any, path: Path_) -> SpeedSegment | None:
    allowed = ("kind", "duration", "to", "peak", "rise", "hold", "fall", "dwell", "repeat")
    d = c.table(raw, path, allowed)
    if not d:
        return None
    kind = c.string(d, path, "kind", choices=SEGMENT_KINDS)
    if kind in ("hold",):
        return SpeedSegment(kind, c.number(d, path, "duration", positive=True))
    if kind in ("step", "ramp", "reversal"):
        to = c.number(d, path, "to", minimum=-4000, maximum=4000)
        dur = c.number(d, path, "duration", 0.0 if kind == "step" else None, minimum=0)
        return SpeedSegment(kind, dur, to=to)
    if kind in ("trapezoid", "triangle"):
        peak = c.number(d, path, "peak", minimum=-4000, maximum=4000)
        rise = c.number(d, path, "rise", positive=True)
        fall = c.number(d, path, "fall", positive=True)
        hold = c.number(d, path, "hold", 0.0, minimum=0) if kind == "trapezoid" else 0.0
        if kind == "triangle" and "hold" in d:
            c.err((*path, "hold"), "a triangle has no hold (use a trapezoid)")
        dwell = c.number(d, path, "dwell", 0.0, minimum=0)
        rep = d.get("repeat", 1)
        if isinstance(rep, bool) or not isinstance(rep, int) or rep < 1:
            c.err((*path, "repeat"), f"must be an integer >= 1, not {rep!r}")
            rep = 1
        dur = (rise + hold + fall + dwell) * rep
        return SpeedSegment(kind, dur, peak=peak, rise=rise, hold=hold, fall=fall,
                            dwell=dwell, repeat=rep)
    return None


def _load_event(c: _Checker, raw: Any, path: Path_, duration: float) -> LoadEvent | None:
    d = c.table(raw, path, ("at", "kind", "torque", "duration", "speed", "k_speed"))
    if not d:
        return None
    kind = c.string(d, path, "kind", choices=LOAD_KINDS)
    at = c.number(d, path, "at", minimum=0.0)
    if at >= duration > 0:
        c.err((*path, "at"), f"{at:g} s is not before the end of the scenario ({duration:g} s)")
    if kind == "step":
        return LoadEvent(at, kind, torque=c.number(d, path, "torque", minimum=-10, maximum=10),
                         k_speed=c.number(d, path, "k_speed", 0.0, minimum=0, maximum=1))
    if kind == "ramp":
        return LoadEvent(at, kind, torque=c.number(d, path, "torque", minimum=-10, maximum=10),
                         duration=c.number(d, path, "duration", positive=True),
                         k_speed=c.number(d, path, "k_speed", 0.0, minimum=0, maximum=1))
    if kind == "speed_hold":
        return LoadEvent(at, kind, speed=c.number(d, path, "speed", minimum=-4000, maximum=4000))
    if kind == "off":
        return LoadEvent(at, kind)
    return None


def _criterion(c: _Checker, raw: Any, path: Path_, duration: float) -> Criterion | None:
    d = c.table(raw, path, ("name", "metric", "window", "limit", "comparison", "params",
                            "profiles", "xfail"))
    if not d:
        return None
    metric = c.string(d, path, "metric")
    if metric and not metrics.known(metric):
        c.err((*path, "metric"), f"unknown metric {metric!r} (see `rig list --metrics`)")
    name = c.string(d, path, "name", metric)
    comparison = c.string(d, path, "comparison", "<=", choices=metrics.COMPARISONS)
    # "report": the value is recorded, any value passes (no data still fails)
    limit = c.number(d, path, "limit", math.nan if comparison == "report" else None)
    profiles: tuple[str, ...] = ()
    if "profiles" in d:
        pr = d["profiles"]
        if not isinstance(pr, list) or not pr or not all(isinstance(x, str) for x in pr):
            c.err((*path, "profiles"), f"must be a non-empty list of profile names, not {pr!r}")
        else:
            for i, x in enumerate(pr):
                if x not in PROFILES:
                    c.err((*path, "profiles", i), f"{x!r} is not one of: {', '.join(PROFILES)}")
            profiles = tuple(pr)
    xfail = c.string(d, path, "xfail", "")
    if "xfail" in d and not xfail.strip():
        c.err((*path, "xfail"), "must give the reason and the measured value")
    window = (0.0, duration)
    if "window" in d:
        w = d["window"]
        wp = (*path, "window")
        if not isinstance(w, list) or len(w) != 2:
            c.err(wp, f"must be [t0, t1] in seconds (t1 may be \"end\"), not {w!r}")
        else:
            t0, t1 = w
            if isinstance(t1, str) and t1 == "end":
                t1 = duration
            ok = True
            for i, v in enumerate((t0, t1)):
                if isinstance(v, bool) or not isinstance(v, int | float):
                    c.err((*wp, i), f"must be a number of seconds, not {v!r}")
                    ok = False
            if ok:
                if not 0 <= t0 < t1:
                    c.err(wp, f"needs 0 <= t0 < t1, got [{t0:g}, {t1:g}]")
                elif t1 > duration + 1e-9:
                    c.err((*wp, 1), f"{t1:g} s is after the end of the scenario ({duration:g} s)")
                window = (float(t0), float(t1))
    params: dict[str, float] = {}
    if "params" in d and metrics.known(metric):
        pd = c.table(d["params"], (*path, "params"), metrics.params_of(metric))
        for k in pd:
            if k in metrics.params_of(metric):
                params[k] = c.number(pd, (*path, "params"), k)
    return Criterion(name, metric, window, limit, comparison, params, profiles, xfail)


def _scalars(c: _Checker, raw: Any, path: Path_) -> dict[str, float | int | str | bool]:
    d = c.table(raw, path, raw.keys() if isinstance(raw, dict) else ())
    flat = profiles.flatten(d)
    for k, v in flat.items():
        if not isinstance(v, int | float | str | bool):
            c.err((*path, *k.split(".")), f"must be a number, string or boolean, not {v!r}")
    return flat


def parse_scenario(file: Path, text: str) -> Scenario:
    """Validates a scenario document; raises ScenarioError listing every problem."""
    c = _Checker(file, text)
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        m = re.search(r"\(at line (\d+)", str(exc))
        raise ScenarioError(
            [Issue(str(file), int(m.group(1)) if m else None, "", f"TOML syntax: {exc}")]
        ) from exc
    if "scenarios" in data or "include" in data:
        raise ScenarioError([Issue(str(file), locate(text, ("scenarios",)), "scenarios",
                                   "this is a suite file, not a scenario")])
    root: Path_ = ()
    c.table(data, root, TOP_KEYS)
    name = c.string(data, root, "name", file.stem)
    if name != file.stem:
        c.err(("name",), f"must match the file name {file.stem!r} (got {name!r})")
    description = c.string(data, root, "description")
    if "\n" in description:
        c.err(("description",), "must be one line")
    profile = c.string(data, root, "profile", choices=PROFILES)
    n_issues = len(c.issues)
    duration = c.number(data, root, "duration", positive=True, maximum=MAX_DURATION_S)
    if len(c.issues) > n_issues:
        duration = math.inf  # reported once; checks that depend on it stay quiet
    figure = c.string(data, root, "figure", "")
    tags: tuple[str, ...] = ()
    if "tags" in data:
        t = data["tags"]
        if not isinstance(t, list) or not all(isinstance(x, str) for x in t):
            c.err(("tags",), "must be a list of strings")
        else:
            tags = tuple(t)
    overrides = _scalars(c, data.get("overrides", {}), ("overrides",))
    firmware = _scalars(c, data.get("firmware", {}), ("firmware",))
    if profile:
        _check_overrides(c, profile, overrides)
    _check_firmware(c, firmware)

    drive = c.table(data.get("drive", {}), ("drive",),
                    ("ctrl_mode", "fw_mode", "enable_at", "iq_ref"))
    ctrl_mode = c.string(drive, ("drive",), "ctrl_mode", "speed",
                         choices=protocols.choices("drive", "DRIVE_CMD", "ctrl_mode"))
    fw_mode = c.string(drive, ("drive",), "fw_mode", "realtime",
                       choices=protocols.choices("drive", "DRIVE_CMD", "fw_mode"))
    enable_at = c.number(drive, ("drive",), "enable_at", 0.0, minimum=0.0)
    iq_ref = c.number(drive, ("drive",), "iq_ref", 0.0, minimum=-10, maximum=10)
    if enable_at >= duration > 0:
        c.err(("drive", "enable_at"), "must be before the end of the scenario")

    limits = c.table(data.get("limits", {}), ("limits",), ("i_max", "speed_max", "step_accel"))
    i_max = c.number(limits, ("limits",), "i_max", 3.0, positive=True, maximum=10)
    speed_max = c.number(limits, ("limits",), "speed_max", 3300.0, positive=True, maximum=4000)
    step_accel = c.number(limits, ("limits",), "step_accel", 0.0, minimum=0.0, maximum=100000)

    initial = c.table(data.get("initial", {}), ("initial",), ("theta_e_deg", "speed_rpm"))
    theta0 = c.number(initial, ("initial",), "theta_e_deg", 0.0, minimum=-360, maximum=360)
    speed0 = c.number(initial, ("initial",), "speed_rpm", 0.0, minimum=-4000, maximum=4000)

    segments: list[SpeedSegment] = []
    raw_speed = data.get("speed", [])
    if not isinstance(raw_speed, list):
        c.err(("speed",), "must be a list of segments ([[speed]] tables)")
        raw_speed = []
    cur = speed0
    t_end = 0.0
    for i, raw in enumerate(raw_speed):
        seg = _segment(c, raw, ("speed", i))
        if seg is None:
            continue
        if seg.kind == "reversal" and seg.to is not None and (
            seg.to == 0 or cur == 0 or math.copysign(1, seg.to) == math.copysign(1, cur)
        ):
            c.err(("speed", i, "to"),
                  f"a reversal goes from one direction to the other ({cur:g} -> {seg.to:g})")
        if seg.to is not None:
            cur = seg.to
        if abs(cur) > speed_max and seg.to is not None:
            c.err(("speed", i, "to"), f"|{cur:g}| r/min exceeds limits.speed_max {speed_max:g}")
        if seg.peak is not None and abs(seg.peak) > speed_max:
            c.err(("speed", i, "peak"), f"exceeds limits.speed_max {speed_max:g}")
        t_end += seg.duration
        segments.append(seg)
    if t_end > duration + 1e-9:
        c.err(("speed",), f"the segments last {t_end:g} s, longer than duration {duration:g} s")

    events: list[LoadEvent] = []
    raw_load = data.get("load", [])
    if not isinstance(raw_load, list):
        c.err(("load",), "must be a list of events ([[load]] tables)")
        raw_load = []
    for i, raw in enumerate(raw_load):
        ev = _load_event(c, raw, ("load", i), duration)
        if ev is not None:
            events.append(ev)

    events_f: list[faults.Fault] = []
    raw_faults = data.get("faults", [])
    if not isinstance(raw_faults, list):
        c.err(("faults",), "must be a list of events ([[faults]] tables)")
        raw_faults = []
    adc_bits = faults.adc_bits_of(profiles.profile_values(profile, overrides)) if profile else {}
    for i, raw in enumerate(raw_faults):
        fe = faults.parse(c, raw, ("faults", i), duration, adc_bits)
        if fe is not None:
            events_f.append(fe)
    faults.check_all(c, events_f, ("faults",))

    crits: list[Criterion] = []
    raw_crit = data.get("criteria", [])
    if not isinstance(raw_crit, list):
        c.err(("criteria",), "must be a list of criteria ([[criteria]] tables)")
        raw_crit = []
    for i, raw in enumerate(raw_crit):
        cr = _criterion(c, raw, ("criteria", i), duration)
        if cr is not None:
            crits.append(cr)
    for i, cr in enumerate(crits):
        for other in crits[:i]:
            if other.name == cr.name and any(
                other.applies_to(pr) and cr.applies_to(pr) for pr in PROFILES
            ):
                c.err(("criteria", i, "name"),
                      f"duplicate criterion name {cr.name!r} (on a common profile)")
                break

    run = c.table(data.get("run", {}), ("run",),
                  ("grant_max_s", "timeout_s", "ready_timeout_s", "realtime_ok"))
    grant = c.number(run, ("run",), "grant_max_s", 0.1, positive=True, maximum=0.1)
    timeout = c.number(run, ("run",), "timeout_s", 0.0, minimum=0.0, maximum=MAX_TIMEOUT_S)
    ready_timeout = c.number(run, ("run",), "ready_timeout_s", 10.0, positive=True,
                             maximum=MAX_READY_TIMEOUT_S)
    realtime_ok = run.get("realtime_ok", True)
    if not isinstance(realtime_ok, bool):
        c.err(("run", "realtime_ok"), "must be true or false")
        realtime_ok = True

    if c.issues:
        raise ScenarioError(c.issues)
    return Scenario(
        name=name, file=file, description=description, profile=profile, duration=duration,
        figure=figure, tags=tags, overrides=overrides, firmware=firmware, ctrl_mode=ctrl_mode,
        fw_mode=fw_mode, enable_at=enable_at, iq_ref=iq_ref, i_max=i_max, speed_max=speed_max,
        step_accel=step_accel, initial_theta_deg=theta0, initial_speed_rpm=speed0,
        speed=tuple(segments), load=tuple(events), faults=tuple(events_f),
        criteria=tuple(crits), grant_max_s=grant,
        timeout_s=timeout, ready_timeout_s=ready_timeout, realtime_ok=realtime_ok,
    )


def parse_suite(file: Path, text: str) -> Suite:
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        m = re.search(r"\(at line (\d+)", str(exc))
        raise ScenarioError(
            [Issue(str(file), int(m.group(1)) if m else None, "", f"TOML syntax: {exc}")]
        ) from exc
    c = _Checker(file, text)
    c.table(data, (), ("name", "description", "include", "scenarios", "comparisons"))
    name = c.string(data, (), "name", file.stem)
    description = c.string(data, (), "description", "")
    scenarios: list[Scenario] = []
    comparisons: list[Comparison] = []
    issues: list[Issue] = []
    included = data.get("include", [])
    if not isinstance(included, list) or not all(isinstance(x, str) for x in included):
        c.err(("include",), "must be a list of suite names")
        included = []
    for i, entry in enumerate(included):
        sub = _suite_path(entry, file.parent)
        if sub is None or sub.resolve() in _including:
            c.err(("include", i), f"no suite {entry!r} (looked in {SUITE_DIR})" if sub is None
                  else f"suite {entry!r} includes itself")
            continue
        _including.add(sub.resolve())
        try:
            inner = load_suite(sub)
        except ScenarioError as exc:
            issues.extend(exc.issues)
            continue
        finally:
            _including.discard(sub.resolve())
        scenarios.extend(inner.scenarios)
        comparisons.extend(inner.comparisons)
    raw = data.get("scenarios", [])
    if not isinstance(raw, list) or not (raw or scenarios):
        c.err(("scenarios",), "must be a non-empty list of scenario names or paths "
                              "(or the suite must include other suites)")
        raw = []
    for i, entry in enumerate(raw):
        if not isinstance(entry, str):
            c.err(("scenarios", i), f"must be a scenario name or path, not {entry!r}")
            continue
        base, _, profile = entry.partition("@")
        if profile and profile not in PROFILES:
            c.err(("scenarios", i), f"profile {profile!r} is not one of: {', '.join(PROFILES)}")
            continue
        target = _scenario_path(base, file.parent)
        if target is None:
            c.err(("scenarios", i), f"no scenario {base!r} (looked in {SCENARIO_DIR})")
            continue
        try:
            sc = _parse_file(target)
        except ScenarioError as exc:
            issues.extend(exc.issues)
            continue
        scenarios.append(sc.with_profile(profile) if profile else _own_profile(sc))
    if not issues:
        comparisons += _comparisons(c, data.get("comparisons", []), scenarios)
    names = [s.name for s in scenarios]
    for dup in sorted({n for n in names if names.count(n) > 1}):
        c.err(("scenarios",), f"{dup!r} appears more than once (its output folder is its name)")
    if c.issues or issues:
        raise ScenarioError(c.issues + issues)
    return Suite(name, file, description, tuple(scenarios), tuple(comparisons))


_including: set[Path] = set()  # suites being parsed (include cycles)


def _suite_path(entry: str, base: Path) -> Path | None:
    for cand in (base / f"{entry}.toml", SUITE_DIR / f"{entry}.toml", Path(entry)):
        if cand.is_file():
            return cand
    return None


COMPARISON_RELATIONS = ("<", "<=", ">", ">=")


def _comparisons(c: _Checker, raw: Any, scenarios: Sequence[Scenario]) -> list[Comparison]:
    if not isinstance(raw, list):
        c.err(("comparisons",), "must be an array of tables ([[comparisons]])")
        return []
    by_name = {s.name: s for s in scenarios}
    out: list[Comparison] = []
    for i, item in enumerate(raw):
        path: Path_ = ("comparisons", i)
        d = c.table(item, path, ("name", "criterion", "a", "b", "relation", "xfail"))
        if not d:
            continue
        crit = c.string(d, path, "criterion")
        runs = []
        for key in ("a", "b"):
            run = c.string(d, path, key)
            sc = by_name.get(run)
            if run and sc is None:
                c.err((*path, key), f"{run!r} is not a scenario of this suite "
                                    f"(entries: {', '.join(by_name) or 'none'})")
            elif sc is not None and crit and not any(
                    cr.name == crit and cr.applies_to(sc.profile) for cr in sc.criteria):
                c.err((*path, "criterion"),
                      f"scenario {run!r} has no criterion named {crit!r} on profile {sc.profile}")
            runs.append(run)
        relation = c.string(d, path, "relation", "<", choices=COMPARISON_RELATIONS)
        name = c.string(d, path, "name", f"{runs[0]} {relation} {runs[1]}: {crit}")
        xfail = c.string(d, path, "xfail", "")
        out.append(Comparison(name, crit, runs[0], runs[1], relation, xfail))
    return out


def _scenario_path(entry: str, base: Path) -> Path | None:
    p = Path(entry)
    for cand in (base / p, base / f"{entry}.toml", p, SCENARIO_DIR / p,
                 SCENARIO_DIR / f"{entry}.toml"):
        if cand.is_file():
            return cand
    return None


def read_text(path: Path) -> str:
    """A scenario or suite file as text; not UTF-8 is a schema error at its line."""
    raw = path.read_bytes()
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = raw.count(b"\n", 0, exc.start) + 1
        raise ScenarioError([Issue(str(path), line, "",
                                   f"not UTF-8 (byte 0x{raw[exc.start]:02x}): TOML files "
                                   "are UTF-8")]) from None


def _parse_file(path: Path) -> Scenario:
    return parse_scenario(path, read_text(path))


def _own_profile(sc: Scenario) -> Scenario:
    """Only the criteria that apply on the scenario's own profile."""
    if all(cr.applies_to(sc.profile) for cr in sc.criteria):
        return sc
    return replace(sc, criteria=tuple(cr for cr in sc.criteria if cr.applies_to(sc.profile)))


def load_scenario(path: str | Path) -> Scenario:
    """A scenario file; only the criteria that apply on its own profile are kept."""
    return _own_profile(_parse_file(Path(path)))


def load_suite(path: str | Path) -> Suite:
    p = Path(path)
    return parse_suite(p, read_text(p))


def is_suite_file(path: Path) -> bool:
    try:
        data = tomllib.loads(read_text(path))
        return "scenarios" in data or "include" in data
    except (OSError, tomllib.TOMLDecodeError, ScenarioError):
        return False


def find(target: str | Path) -> Path:
    """The file of a scenario or suite given by name or path."""
    p = Path(target)
    if p.is_file():
        return p
    for cand in (SCENARIO_DIR / f"{target}.toml", SUITE_DIR / f"{target}.toml"):
        if cand.is_file():
            return cand
    raise FileNotFoundError(
        f"no scenario or suite {str(target)!r} (a file, or a name in {SCENARIO_DIR} or {SUITE_DIR})"
    )


def load(target: str | Path) -> Scenario | Suite:
    """A scenario or a suite, by name or path; ``<scenario>@<profile>`` runs a scenario on
    another fidelity profile."""
    text = str(target)
    if "@" in text and not Path(text).is_file():
        base, _, profile = text.rpartition("@")
        return _parse_file(find(base)).with_profile(profile)
    p = find(target)
    return load_suite(p) if is_suite_file(p) else load_scenario(p)


def scenario_files() -> list[Path]:
    return sorted(SCENARIO_DIR.glob("*.toml"))


def suite_files() -> list[Path]:
    return sorted(SUITE_DIR.glob("*.toml"))


def scenario_names() -> list[str]:
    return [p.stem for p in scenario_files()]


def validate_name(name: str) -> bool:
    return bool(_NAME_RE.match(name))
