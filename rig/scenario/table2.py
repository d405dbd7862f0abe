"""Writes the Table 2 grid scenarios (one file per cell, criteria per profile, xfails with
measured values). This file is their source: edit it, not the generated files.

    python -m rig.scenario.table2 rig/scenarios           # write the files
    python -m rig.scenario.table2 --check rig/scenarios   # exit 1 if any is stale
    python -m rig.scenario.table2 --measured out/ci/paper/result.json
        # take the known failures' measured values from a run (table2_measured.json), then
        # write the files again
"""
from __future__ import annotations

import json
import re
import sys
from pathlib import Path

from rig.scenario.files import SCENARIO_DIR, write_generated

GRID = [(1, 0), (1, 1), (1, 2), (100, 0), (100, 1), (100, 2), (600, 0), (600, 1), (600, 2),
        (1000, 0), (1000, 1), (1000, 2), (2000, 0), (2000, 1), (2000, 2), (3000, 0), (3000, 1.5)]
I_MAX = 4.5
SIX_STEP = ("1.5 N*m at 3000 r/min (2.44 N*m with friction B*w) needs >= {i} A even at the "
            "six-step voltage 2*Vdc/pi = 127 V (computed on the {p} magnetics), above i_max 4.5 A")
ONE_RPM = ("1 r/min holds within ~0.55-0.75 r/min, not 0.5: with J = 0.0005 kg*m^2 a torque "
           "error of 0.2 mN*m (0.3 mA of q current), which the position tracker (2 Hz near "
           "standstill, set by the raw estimate's noise) sees only after ~0.16 s, moves the shaft "
           "by ~0.6 r/min. "
           "The period-mean current the loop controls comes from the samples of the measured "
           "states and a model of the others; with dead time its bias differs by 0.1-0.3 mA "
           "between SVPWM sectors, and at 1 r/min the near-zero voltage reference chatters "
           "between sectors near their boundaries, where the largest excursions lie (in-process "
           "probe: 0.36 r/min without dead time, 0.34 without dead time and device drop). Tried: "
           "a least-squares current fit over the window means (rms 0.20 -> 0.13 r/min, peaks "
           "unchanged), sector hysteresis 0-12 us (better at 0 N*m, worse at 1 and 2 N*m), the "
           "tracker's floor at 0.7-6 Hz instead of 2 Hz (1 N*m, seeds 1-4: 0.86-0.93 r/min at "
           "0.7 Hz, 0.61-0.71 at 1.4 Hz, 0.50-0.53 at 2 Hz, 0.52-0.60 at 3 Hz, 0.62-0.73 at 4 Hz: "
           "2 Hz is the best), the speed PI at half or twice kp and at 3x ki (0.51-0.58), its "
           "speed filter at 10 or 30 Hz instead of 100 (0.51-0.67), the tracker's disturbance pole "
           "at wn instead of wn/2 (0.53-0.68 where it gives 0.52-0.57 at the same seeds), the "
           "dead time the firmware models at 1.5 or 2.5 us instead of the plant's 2 (0.50-0.56). "
           "The torque error itself, measured at 1 N*m against the mean torque of each period "
           "from the shaft's own acceleration (J dw/dt plus the load): the firmware's torque "
           "estimate is 0.3-0.5 mN*m high while the reference alternates between two sectors and "
           "0.1-0.2 mN*m where one sector holds, a step of ~0.25 mN*m once every 60 deg "
           "electrical (5 s at 1 r/min), and the 0.2 s means of the speed peak at 1.16-1.22 r/min "
           "right there")
# Known failures: the reason per (r/min, N*m, profile, metric). The measured values come from
# a run of the grid (table2_measured.json beside this file, refreshed with --measured).
XFAIL: dict[tuple[int, float, str, str], str] = {
    (3000, 1.5, "ideal", "speed_track_err_max_rpm"): SIX_STEP.format(i=4.56, p="ideal"),
    (3000, 1.5, "paper", "speed_track_err_max_rpm"): SIX_STEP.format(i=4.59, p="paper"),
}
for _tq in (0, 1, 2):
    XFAIL[(1, _tq, "paper", "speed_track_err_max_rpm")] = ONE_RPM
MEASURED_FILE = SCENARIO_DIR / "table2_measured.json"
UNITS = {"pos_err_max_deg": "deg", "pos_err_rms_deg": "deg", "speed_track_err_max_rpm": "r/min",
         "polarity_loss_count": "periods"}


def key_text(key: tuple[int, float, str, str]) -> str:
    rpm, torque, profile, metric = key
    return f"{rpm}/{torque:g}/{profile}/{metric}"


def measured() -> dict[str, float]:
    return json.loads(MEASURED_FILE.read_text()) if MEASURED_FILE.is_file() else {}


def xfail_text(key: tuple[int, float, str, str], values: dict[str, float]) -> str:
    v = values.get(key_text(key))
    head = f"measured {v:.3g} {UNITS.get(key[3], '')}".rstrip() if v is not None else \
        "not measured yet"
    return f"{head}: {XFAIL[key]}"


FIRMWARE = {"soc_on_us": 8, "soc_off_us": 1, "soc_per_state": 5}


def tname(t: float) -> str:
    return (f"{t:g}".replace(".", "p")) + "nm"


def cell(rpm: int, torque: float, values: dict[str, float]) -> str:
    t_ramp = max(0.05, rpm / 2000.0)
    t_load = t_ramp + 0.2
    t0 = t_load + (0.2 if torque else 0.0) + 0.4      # settled after the load ramp
    if rpm < 10:
        t0 = 5.0  # start-up (polarity check, speed loop at 1 r/min) is over by then
    rev = 60.0 / (rpm * 2)                            # one electrical revolution, s
    steady = max(0.5, rev * 1.02)
    dur = round(t0 + steady, 2)
    t0 = round(t0, 2)
    # speed held within 0.5 r/min at 1 r/min, 2 at 100, 2 % at 600 and 1000 (at least 10),
    # 1 % at 2000 and 3000 r/min
    trk = {1: 0.5, 100: 2.0, 2000: 20.0, 3000: 30.0}.get(rpm, max(10.0, 0.02 * rpm))
    lines = [
        f"# Table 2 grid cell: steady-state position error at {rpm} r/min, {torque:g} N*m.",
        "# Paper (Table 2, Section V): |error| within 2.5 deg from 1 r/min to 1.5x rated speed.",
        "# Run on every profile from the table2/paper suites (`<name>@<profile>`); criteria",
        "# carry the profiles they apply on. Steady window: after start-up and the load ramp,",
        f"# max(5000 periods, one electrical revolution = {rev:.3g} s) long.",
        f"# i_max {I_MAX} A: above the rated 3 A, as a drive allows for rated torque plus",
        "# friction (2 N*m + B*w needs ~3.6-4.1 A here with q saturation); see the report.",
        f'description = "Table 2 grid: steady state at {rpm} r/min with {torque:g} N*m load"',
        'profile = "paper"',
        f"duration = {dur}",
        'figure = "Table 2"',
        'tags = ["table2", "steady-state"' + (', "slow"]' if rpm < 10 else "]"),
        "",
        "[limits]",
        f"i_max = {I_MAX}",
        "",
        "[firmware]",
    ]
    lines += [f"{k} = {v}" for k, v in FIRMWARE.items()]
    if rpm < 10:
        lines += ["", "[run]", "timeout_s = 600.0"]
    lines += ["", "[[speed]]", 'kind = "ramp"', f"to = {float(rpm)}", f"duration = {t_ramp:.3f}",
              "", "[[speed]]", 'kind = "hold"', f"duration = {dur - t_ramp:.3f}"]
    if torque:
        lines += ["", "[[load]]", f"at = {t_load:.3f}", 'kind = "ramp"', f"torque = {torque:g}",
                  "duration = 0.2"]

    def crit(name: str, metric: str, limit: float | None, comp: str = "<=",
             profiles: list[str] | None = None, w0: float = t0, better: str = "") -> None:
        lines.extend(["", "[[criteria]]", f'name = "{name}"', f'metric = "{metric}"',
                      f'window = [{w0}, "end"]'])
        xf = [xfail_text((rpm, torque, pr, metric), values)
              for pr in (profiles or ["ideal", "paper", "harsh"])
              if (rpm, torque, pr, metric) in XFAIL]
        if xf and profiles and len(profiles) == 1:
            lines.append(f'xfail = "{xf[0]}"')
        if limit is not None:
            lines.append(f"limit = {limit:g}")
        if comp != "<=":
            lines.append(f'comparison = "{comp}"')
        if better:
            lines.append(f'better = "{better}"')
        if profiles:
            lines.append("profiles = [" + ", ".join(f'"{p}"' for p in profiles) + "]")

    crit("steady-state position error", "pos_err_max_deg", 0.5, profiles=["ideal"])
    crit("steady-state position error", "pos_err_max_deg", 2.5, profiles=["paper"])
    crit("steady-state position error", "pos_err_max_deg", 5.0, profiles=["harsh"])
    crit("position error against the 1 deg target", "pos_err_max_deg", 1.0, profiles=["paper"])
    crit("RMS position error", "pos_err_rms_deg", 1.5, profiles=["ideal"])
    crit("RMS position error", "pos_err_rms_deg", 1.5, profiles=["paper"])
    # harsh: the same ratio to its 5 deg spec as paper's 1.5 to its 2.5 (0.6)
    crit("RMS position error", "pos_err_rms_deg", 3.0, profiles=["harsh"])
    for pr in ("ideal", "paper", "harsh"):
        crit("no polarity loss", "polarity_loss_count", 0, "==", profiles=[pr], w0=0.1)
    for pr in ("ideal", "paper"):
        crit("speed holds", "speed_track_err_max_rpm", trk, profiles=[pr])
    # harsh: no limit of its own beyond the paper's spec (the position), its baseline bounds it
    crit("speed holds", "speed_track_err_max_rpm", None, "report", ["harsh"], better="lower")
    if rpm < 10:
        # the speed-hold criterion bounds the excursions; this says the shaft does turn
        for pr in ("ideal", "paper", "harsh"):
            crit("the shaft turns at 1 r/min", "speed_mean_rpm", 0.9, ">=", profiles=[pr])
            crit("the shaft turns no faster", "speed_mean_rpm", 1.1, profiles=[pr])
    if torque:
        # the torque the drive reports (te_hat, from its currents and parameters) against the
        # plant's: within 5 % of rated (2 N*m) where the parameters are known or learnt
        for pr in ("ideal", "paper"):
            crit("torque estimate error", "te_err_max_nm", 0.1, profiles=[pr])
        crit("torque estimate error", "te_err_max_nm", None, "report", ["harsh"],
             better="lower")
    windows = ISR_COST.get((rpm, torque))
    if windows:
        lines.extend(["", *ISR_COST_NOTE])
        for what, a, b in windows:
            for stat, metric in (("median", "isr_instructions_median"),
                                 ("worst", "isr_instructions_max")):
                lines.extend(["", "[[criteria]]",
                              f'name = "ISR instructions on the Cortex-M4F, {stat} ({what})"',
                              f'metric = "{metric}"', f"window = [{a}, {b}]",
                              'comparison = "report"', 'better = "lower"',
                              'profiles = ["paper"]'])
    return "\n".join(lines) + "\n"


# The ISR's cost on the emulated Cortex-M4F (issue 40) in the cells of the gate's sample that
# covers every state and path of the ISR: (rpm, torque) -> (what, window start, window end)
ISR_COST: dict[tuple[int, float], list[tuple[str, float, float]]] = {
    (1, 1): [("the start: INIT, IDLE, the standstill polarity test, RUN", 0.0, 0.15),
             ("1 r/min, 1 N*m: slopes, polarity watch", 1.9, 1.95)],
    (1000, 1): [("1000 r/min, the load ramp", 0.69, 0.74)],
}
ISR_COST_NOTE = [
    "# The ISR's cost on the emulated Cortex-M4F (rig.target_m4.cost, issue 40): fw_core_isr's",
    "# instructions per period over the window, median and worst, judged against the baseline",
    "# (5 % of the mean or more on the worse side is a regression; its message names the step of",
    "# fw_core_isr that grew). In-process runs only. This scenario is one of the gate's sample",
    "# that covers every state and path of the ISR: firmware_c2000/core/README.md (The ISR's cost",
    "# in the gate).",
]


def render() -> dict[str, str]:
    """File name -> content of every grid cell."""
    values = measured()
    return {f"table2_{rpm:04d}rpm_{tname(tq)}.toml": cell(rpm, tq, values) for rpm, tq in GRID}


_CELL = re.compile(r"^table2_(\d{4})rpm_(\d+(?:p\d+)?)nm@(\w+)$")


def refresh(result_json: Path) -> int:
    """Takes the measured values of the known failures from a suite result (table2 or paper)
    and lists what no longer matches: failures without an xfail, xfails that passed."""
    summary = json.loads(result_json.read_text())
    values = measured()
    problems = []
    for entry in summary["scenarios"]:
        m = _CELL.match(entry["name"])
        if not m:
            continue
        rpm, torque, profile = int(m.group(1)), float(m.group(2).replace("p", ".")), m.group(3)
        for c in entry.get("criteria") or []:
            key = (rpm, torque, profile, c["metric"])
            if key in XFAIL and c.get("value") is not None:
                values[key_text(key)] = round(float(c["value"]), 4)
            if c.get("outcome") == "fail":
                problems.append(f"new failure (add an XFAIL): {entry['name']} {c['name']} = "
                                f"{c.get('value')}")
            elif c.get("outcome") == "xpass":
                problems.append(f"passes now (remove its XFAIL): {entry['name']} {c['name']}")
    known = {key_text(k) for k in XFAIL}
    values = {k: v for k, v in values.items() if k in known}  # (failures fixed since: gone)
    MEASURED_FILE.write_text(json.dumps(dict(sorted(values.items())), indent=1) + "\n")
    print("\n".join(problems) or "every known failure measured, no new failures")
    return 1 if problems else 0


def main(argv: list[str]) -> int:
    if argv[:1] == ["--measured"]:
        return refresh(Path(argv[1]))
    check = "--check" in argv
    out = Path(next(a for a in argv if a != "--check"))
    stale = write_generated(render(), out, check)
    if stale:
        print("stale (run python -m rig.scenario.table2 rig/scenarios):", *stale)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
