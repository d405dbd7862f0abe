"""A scenario file's fields, checked: every schema error with its file, line and field
(``file:line: field: message``), all of them at once; the wire enumerations (control
modes, flux-weakening modes) from the DBC's value tables."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from rig import protocols
from rig.bench import profiles
from rig.data import metrics
from rig.scenario import faults
from rig.scenario.checks import check_firmware, check_overrides
from rig.scenario.model import (
    PROFILES,
    Criterion,
    LoadEvent,
    Scenario,
    SpeedSegment,
    side_of,
)
from rig.scenario.positions import Path_, locate
from rig.scenario.schema import Checker, Issue, ScenarioError, finite, parse_toml, read_text, shown

SEGMENT_KINDS = ("hold", "step", "ramp", "reversal", "trapezoid", "triangle")
LOAD_KINDS = ("step", "ramp", "off", "speed_hold")
# Upper bounds of the run's own numbers: a duration that would make the grant plan and the
# traces unbounded (1e7 s: MemoryError), and waits no run needs.
MAX_DURATION_S = 3600.0
MAX_TIMEOUT_S = 86400.0
MAX_READY_TIMEOUT_S = 600.0
# criteria: which way a value improves (the baseline's better side)
BETTER_SIDES = ("lower", "higher", "either")
# [run] seeds: a verdict over seeds needs a few to have a spread, and stays affordable
MIN_SEEDS = 3
MAX_SEEDS = 32

MAX_REPEAT = 100_000  # cycles of a periodic speed segment (the duration is bounded too)


TOP_KEYS = (
    "name", "description", "profile", "duration", "figure", "tags", "overrides", "firmware",
    "drive", "limits", "initial", "speed", "load", "faults", "criteria", "run",
)


def _segment(c: Checker, raw: Any, path: Path_) -> SpeedSegment | None:
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
        if isinstance(rep, bool) or not isinstance(rep, int) or not 1 <= rep <= MAX_REPEAT:
            c.err((*path, "repeat"), f"must be an integer >= 1 (at most {MAX_REPEAT}), not "
                  f"{shown(rep)}")
            rep = 1
        dur = (rise + hold + fall + dwell) * rep
        return SpeedSegment(kind, dur, peak=peak, rise=rise, hold=hold, fall=fall,
                            dwell=dwell, repeat=rep)
    return None


def _load_event(c: Checker, raw: Any, path: Path_, duration: float) -> LoadEvent | None:
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


def _criterion(c: Checker, raw: Any, path: Path_, duration: float) -> Criterion | None:
    d = c.table(raw, path, ("name", "metric", "window", "limit", "comparison", "params",
                            "profiles", "xfail", "better"))
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
            given = (t0,) if isinstance(t1, str) and t1 == "end" else (t0, t1)
            if isinstance(t1, str) and t1 == "end":
                t1 = duration  # (an invalid duration is reported as such)
            ok = True
            for i, v in enumerate(given):
                if finite(v) is None:
                    c.err((*wp, i), f"must be a finite number of seconds, not {shown(v)}")
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
    # which way the value improves, for the baseline (rig.regression.baseline): from the comparison
    # ("<=": lower), or given for a reported value ("either": any move beyond the seed
    # spread counts)
    default_better = side_of(comparison)
    better = c.string(d, path, "better", "", choices=BETTER_SIDES)
    if better and comparison in ("<", "<=", ">", ">=") and better != default_better:
        c.err((*path, "better"), f"a {comparison!r} criterion improves towards the "
              f"{default_better} side, not {better!r}")
    return Criterion(name, metric, window, limit, comparison, params, profiles, xfail, better)


def _scalars(c: Checker, raw: Any, path: Path_) -> dict[str, float | int | str | bool]:
    d = c.table(raw, path, raw.keys() if isinstance(raw, dict) else ())
    flat = profiles.flatten(d)
    for k, v in list(flat.items()):
        if not isinstance(v, int | float | str | bool):
            c.err((*path, *k.split(".")), f"must be a number, string or boolean, not {v!r}")
        elif not isinstance(v, bool | str) and finite(v) is None:
            # judged here: the programs' loaders would echo a 400-digit integer whole
            c.err((*path, *k.split(".")), f"must be a finite number, not {shown(v)}")
            del flat[k]
    return flat


def parse_scenario(file: Path, text: str) -> Scenario:
    """Validates a scenario document; raises ScenarioError listing every problem."""
    c = Checker(file, text)
    data = parse_toml(file, text)
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
        check_overrides(c, profile, overrides)
    check_firmware(c, firmware)

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
                  ("grant_max_s", "timeout_s", "ready_timeout_s", "realtime_ok", "seeds"))
    grant = c.number(run, ("run",), "grant_max_s", 0.1, positive=True, maximum=0.1)
    timeout = c.number(run, ("run",), "timeout_s", 0.0, minimum=0.0, maximum=MAX_TIMEOUT_S)
    ready_timeout = c.number(run, ("run",), "ready_timeout_s", 10.0, positive=True,
                             maximum=MAX_READY_TIMEOUT_S)
    realtime_ok = run.get("realtime_ok", True)
    if not isinstance(realtime_ok, bool):
        c.err(("run", "realtime_ok"), "must be true or false")
        realtime_ok = True

    seeds = _seeds(c, run.get("seeds"))

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
        seeds=seeds,
    )


def _seeds(c: Checker, raw: Any) -> tuple[int, ...]:
    """``[run] seeds``: a count N (seeds 1..N) or a list of distinct seeds; the scenario's
    criteria are then decided over all of them (rig.run.multi_seed)."""
    if raw is None:
        return ()
    where = ("run", "seeds")
    if isinstance(raw, int) and not isinstance(raw, bool):
        seeds = list(range(1, raw + 1)) if 0 < raw <= MAX_SEEDS else []
    elif isinstance(raw, list) and all(isinstance(x, int) and not isinstance(x, bool)
                                       for x in raw):
        seeds = list(raw)
    else:
        c.err(where, "must be a number of seeds or a list of seeds (whole numbers)")
        return ()
    if not MIN_SEEDS <= len(seeds) <= MAX_SEEDS or len(set(seeds)) != len(seeds) or \
            any(not 0 <= x < 2**31 for x in seeds):
        c.err(where, f"must be a count of {MIN_SEEDS} to {MAX_SEEDS} seeds or a list of as many "
              "distinct seeds in 0 .. 2^31 - 1")
        return ()
    return tuple(seeds)


def parse_file(path: Path) -> Scenario:
    return parse_scenario(path, read_text(path))


def load_scenario(path: str | Path) -> Scenario:
    """A scenario file; only the criteria that apply on its own profile are kept."""
    return parse_file(Path(path)).on_own_profile()
