"""Writes the start scenarios of the suite `starts` (a load already on the shaft at the enable,
and flying starts), one file each, with their criteria per profile and the measured values
behind the regression limits. This file is their source: edit it, not the generated files.

    python -m rig.scenario.starts rig/scenarios           # write the files
    python -m rig.scenario.starts --check rig/scenarios   # exit 1 if any is stale
"""
from __future__ import annotations

import sys
from pathlib import Path

from rig.scenario.files import SCENARIO_DIR, write_generated

I_MAX = 4.5
I_PEAK = 4.7  # i_max plus the PWM ripple the Fig. 10 scenarios allow at the voltage limit
# braking against a load at i_max: the PWM ripple and the current loop's overshoot as the
# reference steps to the limit (measured 4.71-4.74 A on ideal, every seed)
I_PEAK_BRAKE = 4.8
# from ~2500 r/min flux weakening takes i_max into d (the idle inverter's diodes already conduct
# at the enable): the ripple of FULL modulation near six-step on top, 4.65-4.69 A in the Fig. 10
# scenarios' steady running at 3000 r/min on paper, 4.54-4.73 A after the catch (seeds 1-8)
I_PEAK_FW = 4.8
PROFILES = ("ideal", "paper", "harsh")
# the usual position limits after the recovery (Table 2, robustness load steps)
POS_LIMIT = {"ideal": 0.5, "paper": 2.5, "harsh": 5.0}

# Start against a load: (name, load N*m, start angle deg). The load opposes positive
# rotation, so a positive one turns the shaft backwards from the enable on.
LOAD_STARTS = [
    ("start_load_p2nm_040deg", 2.0, 40.0),
    ("start_load_m2nm_200deg", -2.0, 200.0),
    ("start_load_p1nm_110deg", 1.0, 110.0),
    ("start_load_m1nm_290deg", -1.0, 290.0),
    ("start_load_p05nm_330deg", 0.5, 330.0),
]
# Flying starts: (name, speed r/min, start angle deg): the load machine holds the shaft
# at that speed until the enable at 10 ms and lets it go then.
RELEASE = 0.01  # the load machine lets go of the shaft at the enable
FLYING = [
    ("start_fly_p3000", 3000.0, 20.0),
    ("start_fly_m3000", -3000.0, 140.0),
    ("start_fly_p2000", 2000.0, 260.0),
    ("start_fly_m1000", -1000.0, 75.0),
    ("start_fly_p1000", 1000.0, 310.0),
    ("start_fly_m600", -600.0, 190.0),
    ("start_fly_p300", 300.0, 100.0),
    ("start_fly_m300", -300.0, 230.0),
]

# Regression limits: what a plausible regression breaks, above the largest value measured over
# noise seeds 1-8 on every profile (MEASURED, refreshed from runs of the suite).
MEASURED: dict[tuple[str, str], float] = {
    ('start_fly_m1000', 'harsh:pos_err_max_deg'): 4.8736,
    ('start_fly_m1000', 'harsh:pos_err_max_deg@ramp'): 2.9593,
    ('start_fly_m1000', 'harsh:run_time_s'): 0.0031,
    ('start_fly_m1000', 'harsh:speed_track_err_max_rpm'): 25.9736,
    ('start_fly_m1000', 'ideal:pos_err_max_deg'): 0.1512,
    ('start_fly_m1000', 'ideal:pos_err_max_deg@ramp'): 0.0539,
    ('start_fly_m1000', 'ideal:run_time_s'): 0.0011,
    ('start_fly_m1000', 'ideal:speed_track_err_max_rpm'): 1.0345,
    ('start_fly_m1000', 'paper:pos_err_max_deg'): 0.7251,
    ('start_fly_m1000', 'paper:pos_err_max_deg@ramp'): 0.5671,
    ('start_fly_m1000', 'paper:run_time_s'): 0.0031,
    ('start_fly_m1000', 'paper:speed_track_err_max_rpm'): 7.7706,
    ('start_fly_m300', 'harsh:pos_err_max_deg'): 4.7891,
    ('start_fly_m300', 'harsh:pos_err_max_deg@ramp'): 2.5403,
    ('start_fly_m300', 'harsh:run_time_s'): 0.0071,
    ('start_fly_m300', 'harsh:speed_track_err_max_rpm'): 135.345,
    ('start_fly_m300', 'ideal:pos_err_max_deg'): 0.0167,
    ('start_fly_m300', 'ideal:pos_err_max_deg@ramp'): 0.0487,
    ('start_fly_m300', 'ideal:run_time_s'): 0.0031,
    ('start_fly_m300', 'ideal:speed_track_err_max_rpm'): 1.4625,
    ('start_fly_m300', 'paper:pos_err_max_deg'): 1.1454,
    ('start_fly_m300', 'paper:pos_err_max_deg@ramp'): 0.909,
    ('start_fly_m300', 'paper:run_time_s'): 0.0049,
    ('start_fly_m300', 'paper:speed_track_err_max_rpm'): 61.0927,
    ('start_fly_m3000', 'harsh:pos_err_max_deg'): 3.975,
    ('start_fly_m3000', 'harsh:pos_err_max_deg@ramp'): 1.4804,
    ('start_fly_m3000', 'harsh:run_time_s'): 0.0011,
    ('start_fly_m3000', 'harsh:speed_track_err_max_rpm'): 350.1442,
    ('start_fly_m3000', 'ideal:pos_err_max_deg'): 1.1719,
    ('start_fly_m3000', 'ideal:pos_err_max_deg@ramp'): 0.7886,
    ('start_fly_m3000', 'ideal:run_time_s'): 0.0008,
    ('start_fly_m3000', 'ideal:speed_track_err_max_rpm'): 197.6571,
    ('start_fly_m3000', 'paper:pos_err_max_deg'): 1.7295,
    ('start_fly_m3000', 'paper:pos_err_max_deg@ramp'): 1.1289,
    ('start_fly_m3000', 'paper:run_time_s'): 0.0008,
    ('start_fly_m3000', 'paper:speed_track_err_max_rpm'): 165.0497,
    ('start_fly_m600', 'harsh:pos_err_max_deg'): 5.3278,
    ('start_fly_m600', 'harsh:pos_err_max_deg@ramp'): 2.4783,
    ('start_fly_m600', 'harsh:run_time_s'): 0.0053,
    ('start_fly_m600', 'harsh:speed_track_err_max_rpm'): 149.9312,
    ('start_fly_m600', 'ideal:pos_err_max_deg'): 0.0578,
    ('start_fly_m600', 'ideal:pos_err_max_deg@ramp'): 0.0446,
    ('start_fly_m600', 'ideal:run_time_s'): 0.0017,
    ('start_fly_m600', 'ideal:speed_track_err_max_rpm'): 4.2569,
    ('start_fly_m600', 'paper:pos_err_max_deg'): 0.9905,
    ('start_fly_m600', 'paper:pos_err_max_deg@ramp'): 0.723,
    ('start_fly_m600', 'paper:run_time_s'): 0.0031,
    ('start_fly_m600', 'paper:speed_track_err_max_rpm'): 4.6545,
    ('start_fly_p1000', 'harsh:pos_err_max_deg'): 4.9244,
    ('start_fly_p1000', 'harsh:pos_err_max_deg@ramp'): 3.1328,
    ('start_fly_p1000', 'harsh:run_time_s'): 0.0031,
    ('start_fly_p1000', 'harsh:speed_track_err_max_rpm'): 25.0303,
    ('start_fly_p1000', 'ideal:pos_err_max_deg'): 0.0566,
    ('start_fly_p1000', 'ideal:pos_err_max_deg@ramp'): 0.0688,
    ('start_fly_p1000', 'ideal:run_time_s'): 0.0023,
    ('start_fly_p1000', 'ideal:speed_track_err_max_rpm'): 1.8638,
    ('start_fly_p1000', 'paper:pos_err_max_deg'): 0.9046,
    ('start_fly_p1000', 'paper:pos_err_max_deg@ramp'): 0.5842,
    ('start_fly_p1000', 'paper:run_time_s'): 0.0031,
    ('start_fly_p1000', 'paper:speed_track_err_max_rpm'): 6.9811,
    ('start_fly_p2000', 'harsh:pos_err_max_deg'): 4.3566,
    ('start_fly_p2000', 'harsh:pos_err_max_deg@ramp'): 5.9025,
    ('start_fly_p2000', 'harsh:run_time_s'): 0.0031,
    ('start_fly_p2000', 'harsh:speed_track_err_max_rpm'): 22.7657,
    ('start_fly_p2000', 'ideal:pos_err_max_deg'): 2.2066,
    ('start_fly_p2000', 'ideal:pos_err_max_deg@ramp'): 0.4462,
    ('start_fly_p2000', 'ideal:run_time_s'): 0.0031,
    ('start_fly_p2000', 'ideal:speed_track_err_max_rpm'): 20.4071,
    ('start_fly_p2000', 'paper:pos_err_max_deg'): 2.2555,
    ('start_fly_p2000', 'paper:pos_err_max_deg@ramp'): 0.6938,
    ('start_fly_p2000', 'paper:run_time_s'): 0.0031,
    ('start_fly_p2000', 'paper:speed_track_err_max_rpm'): 15.698,
    ('start_fly_p300', 'harsh:pos_err_max_deg'): 5.1761,
    ('start_fly_p300', 'harsh:pos_err_max_deg@ramp'): 2.0649,
    ('start_fly_p300', 'harsh:run_time_s'): 0.0068,
    ('start_fly_p300', 'harsh:speed_track_err_max_rpm'): 133.8978,
    ('start_fly_p300', 'ideal:pos_err_max_deg'): 0.031,
    ('start_fly_p300', 'ideal:pos_err_max_deg@ramp'): 0.0486,
    ('start_fly_p300', 'ideal:run_time_s'): 0.002,
    ('start_fly_p300', 'ideal:speed_track_err_max_rpm'): 0.1552,
    ('start_fly_p300', 'paper:pos_err_max_deg'): 1.179,
    ('start_fly_p300', 'paper:pos_err_max_deg@ramp'): 0.8739,
    ('start_fly_p300', 'paper:run_time_s'): 0.0049,
    ('start_fly_p300', 'paper:speed_track_err_max_rpm'): 58.003,
    ('start_fly_p3000', 'harsh:pos_err_max_deg'): 3.1265,
    ('start_fly_p3000', 'harsh:pos_err_max_deg@ramp'): 1.3926,
    ('start_fly_p3000', 'harsh:run_time_s'): 0.0017,
    ('start_fly_p3000', 'harsh:speed_track_err_max_rpm'): 336.6249,
    ('start_fly_p3000', 'ideal:pos_err_max_deg'): 0.7876,
    ('start_fly_p3000', 'ideal:pos_err_max_deg@ramp'): 1.0371,
    ('start_fly_p3000', 'ideal:run_time_s'): 0.0007,
    ('start_fly_p3000', 'ideal:speed_track_err_max_rpm'): 142.4639,
    ('start_fly_p3000', 'paper:pos_err_max_deg'): 3.3054,
    ('start_fly_p3000', 'paper:pos_err_max_deg@ramp'): 1.0383,
    ('start_fly_p3000', 'paper:run_time_s'): 0.0012,
    ('start_fly_p3000', 'paper:speed_track_err_max_rpm'): 156.3598,
    ('start_load_m1nm_290deg', 'harsh:kickback_deg'): 74.5775,
    ('start_load_m1nm_290deg', 'harsh:torque_time_s'): 0.0142,
    ('start_load_m1nm_290deg', 'ideal:kickback_deg'): 37.2614,
    ('start_load_m1nm_290deg', 'ideal:torque_time_s'): 0.0101,
    ('start_load_m1nm_290deg', 'paper:kickback_deg'): 39.6145,
    ('start_load_m1nm_290deg', 'paper:torque_time_s'): 0.0103,
    ('start_load_m2nm_200deg', 'harsh:kickback_deg'): 106.1737,
    ('start_load_m2nm_200deg', 'harsh:torque_time_s'): 0.0091,
    ('start_load_m2nm_200deg', 'ideal:kickback_deg'): 67.8802,
    ('start_load_m2nm_200deg', 'ideal:torque_time_s'): 0.0076,
    ('start_load_m2nm_200deg', 'paper:kickback_deg'): 69.1045,
    ('start_load_m2nm_200deg', 'paper:torque_time_s'): 0.0074,
    ('start_load_p05nm_330deg', 'harsh:kickback_deg'): 24.3956,
    ('start_load_p05nm_330deg', 'harsh:torque_time_s'): 0.0139,
    ('start_load_p05nm_330deg', 'ideal:kickback_deg'): 21.6673,
    ('start_load_p05nm_330deg', 'ideal:torque_time_s'): 0.014,
    ('start_load_p05nm_330deg', 'paper:kickback_deg'): 21.2675,
    ('start_load_p05nm_330deg', 'paper:torque_time_s'): 0.0124,
    ('start_load_p1nm_110deg', 'harsh:kickback_deg'): 50.7088,
    ('start_load_p1nm_110deg', 'harsh:torque_time_s'): 0.0113,
    ('start_load_p1nm_110deg', 'ideal:kickback_deg'): 37.5784,
    ('start_load_p1nm_110deg', 'ideal:torque_time_s'): 0.0102,
    ('start_load_p1nm_110deg', 'paper:kickback_deg'): 37.4876,
    ('start_load_p1nm_110deg', 'paper:torque_time_s'): 0.0098,
    ('start_load_p2nm_040deg', 'harsh:kickback_deg'): 114.7714,
    ('start_load_p2nm_040deg', 'harsh:torque_time_s'): 0.0098,
    ('start_load_p2nm_040deg', 'ideal:kickback_deg'): 67.9404,
    ('start_load_p2nm_040deg', 'ideal:torque_time_s'): 0.0076,
    ('start_load_p2nm_040deg', 'paper:kickback_deg'): 71.268,
    ('start_load_p2nm_040deg', 'paper:torque_time_s'): 0.0077,
}
# Known failures: (scenario, profile, criterion) -> reason with the measured value
_FW_3000 = ("measured {v} deg (every seed) against 0.5 from 0.2 s: at 3000 r/min on ideal the "
            "catch leaves flux weakening's loop (i_max all in d for ~20 ms) settling for ~0.5 s "
            "(1.0 deg until 0.5 s, 0.04 deg from 0.6 s; Table 2 at 3000 r/min on ideal: 0.04 deg)")
XFAIL: dict[tuple[str, str, str], str] = {
    ("start_fly_p3000", "ideal", "position error"): _FW_3000.format(v="1.04"),
    ("start_fly_m3000", "ideal", "position error"): _FW_3000.format(v="1.02"),
}
# Decided over their own seeds (worst of eight): at rated load the start sits at the edge of
# the saliency the slopes need. Until the back-EMF line was extended back to the enable, the
# speed the recovery returns to was the shaft's ~2.5 ms after it (~100 r/min at 2 N*m), and
# the reference stepped from there to the command: at -2 N*m on paper seed 3 lost the
# position once (+1670 r/min, 4.95 A); now every seed holds it.
OWN_SEEDS = {"start_load_p2nm_040deg": 8, "start_load_m2nm_200deg": 8}
# Left out of the suite: their verdict depends on the noise seed (seeds 1-8 measured); what
# fails is the reason (firmware_c2000/core/README.md, Limits known). None now: the 2 N*m
# starts on paper pass at seeds 1-8, at the edge (before the core's own trigonometry, a little
# different numerically, seed 2 ran off to -1586 r/min at +2 N*m and seed 7 to +1563 r/min at
# -2 N*m: one polarity-loss episode each, corrected; the q current that holds 2 N*m lies at the
# edge of the saliency the slopes need); their baselines hold them where they are.
NOT_IN_SUITE: dict[tuple[str, str], str] = {}


def _fmt(v: float) -> str:
    return repr(float(v)) if isinstance(v, float) else repr(v)


def _crit(name: str, metric: str, window: tuple[float, float | str], *, limit: float | None = None,
          comparison: str = "<=", profiles: tuple[str, ...] = (), params: str = "",
          xfail: str = "", better: str = "") -> str:
    w1 = f'"{window[1]}"' if isinstance(window[1], str) else _fmt(window[1])
    out = ["[[criteria]]", f'name = "{name}"', f'metric = "{metric}"',
           f"window = [{_fmt(window[0])}, {w1}]"]
    if comparison == "report":
        out.append('comparison = "report"')
        if better:
            out.append(f'better = "{better}"')
    else:
        out.append(f"limit = {_fmt(limit if limit is not None else 0.0)}")
        if comparison != "<=":
            out.append(f'comparison = "{comparison}"')
    if params:
        out.append(f"params = {{ {params} }}")
    if profiles:
        out.append("profiles = [" + ", ".join(f'"{p}"' for p in profiles) + "]")
    if xfail:
        out.append(f'xfail = "{xfail}"')
    return "\n".join(out) + "\n"


# The ISR's cost on the emulated Cortex-M4F (rig.target_m4.cost, issue 40) over the start,
# from the enable through the start's own test into RUN: the back-EMF test (300 r/min) and
# the catch (1000 r/min), the two start paths no other scenario of the sample takes. Judged
# on `paper` only (the profile's noise and timing are the same code paths).
ISR_COST = {"start_fly_p300": "the back-EMF test", "start_fly_p1000": "the catch"}


def _isr_cost(what: str) -> list[str]:
    return [_crit(f"ISR instructions on the Cortex-M4F, {stat} ({what})", metric, (0.0, 0.06),
                  comparison="report", better="lower", profiles=("paper",))
            for stat, metric in (("median", "isr_instructions_median"),
                                 ("worst", "isr_instructions_max"))]


def _per_profile(name: str, metric: str, window: tuple[float, float | str],
                 limits: dict[str, float], scen: str, **kw: str) -> list[str]:
    return [_crit(name, metric, window, limit=limits[p], profiles=(p,),
                  xfail=XFAIL.get((scen, p, name), ""), **kw) for p in PROFILES]


def _regression(scen: str, name: str, metric: str, window: tuple[float, float | str],
                factor: float, floor: float, key: str = "", **kw: str) -> list[str]:
    """A value held to what the drive does: reported, lower is better, and its committed
    baseline (rig/baselines/starts.toml) fails a run that moves it beyond its spread over the
    noise seeds. (It was a limit of factor times the largest value over seeds 1-8, at least
    floor: a limit that close to the noise decided by the seed, as recording the baseline
    with the seed's start-angle dither showed; the baseline's band is made for this.)"""
    del factor, floor, key
    return [_crit(name.replace(" (regression)", " (held by its baseline)"), metric, window,
                  comparison="report", better="lower", **kw)]


def load_start(name: str, torque: float, angle: float) -> str:
    back = "backwards" if torque > 0 else "forwards"
    own_seeds = (f"\n[run]\n# decided on the worst of {OWN_SEEDS[name]} seeds (OWN_SEEDS)\n"
                 f"seeds = {OWN_SEEDS[name]}\n") if name in OWN_SEEDS else ""
    head = f"""# Start against a load: {abs(torque):g} N*m already on the shaft at the enable
# (t = 0), turning it {back}; start angle {angle:g} deg (electrical); the profile's noise
# seed (verdicts checked over seeds 1-8). Written by rig/scenario/starts.py: edit that.
# Until the drive has decided the polarity it makes no torque it knows the sign of, and the
# load accelerates the light shaft (J = 0.0005 kg*m^2) at TL/J; the back-EMF test decides
# once the shaft has turned ~10 deg electrical, then the speed loop starts with the load's
# current and brings the shaft back to standstill, then the profile: 100 r/min.
description = "Start with {torque:+g} N*m on the shaft at {angle:g} deg: torque, kick-back, \
then 100 r/min"
profile = "paper"
duration = 1.0
figure = "Starts"
tags = ["starts", "load-start", "low-speed"]
{own_seeds}
[initial]
theta_e_deg = {angle:g}

[limits]
i_max = {I_MAX}

[firmware]
soc_on_us = 8
soc_off_us = 1
soc_per_state = 5

[[speed]]
kind = "hold"
duration = 0.4

[[speed]]
kind = "ramp"
to = 100.0
duration = 0.2

[[speed]]
kind = "hold"
duration = 0.4

[[load]]
at = 0.0
kind = "step"
torque = {torque:g}

"""
    crits: list[str] = []
    crits += _per_profile("torque within 20 ms", "torque_time_s", (0.0, "end"),
                          dict.fromkeys(PROFILES, 0.02), name)
    # (until the profile moves the shaft: from 0.4 s it turns forwards on its own; held by
    # its baseline, as the torque time beside its limit)
    crits.append(_crit("shaft kick-back", "kickback_deg", (0.0, 0.4), comparison="report",
                       better="lower"))
    metric = "speed_min_rpm" if torque > 0 else "speed_max_rpm"
    crits.append(_crit("kick-back speed", metric, (0.0, 0.4), comparison="report"))
    crits += _per_profile("no polarity loss", "polarity_loss_count", (0.05, "end"),
                          dict.fromkeys(PROFILES, 0), name, comparison="==")
    crits.append(_crit("stays in RUN", "fw_state_end", (0.05, "end"), limit=3, comparison="=="))
    crits += _per_profile("current within i_max", "i_mag_max_a", (0.0, "end"),
                          dict.fromkeys(PROFILES, I_PEAK_BRAKE), name)
    crits += _per_profile("position error after the recovery", "pos_err_max_deg", (0.5, "end"),
                          POS_LIMIT, name)
    return head + "\n".join(crits)


def flying(name: str, speed: float, angle: float) -> str:
    head = f"""# Flying start: the shaft turns at {speed:+g} r/min at the enable (t = 10 ms),
# held there by the load machine until then (the inverter idle: above ~2500 r/min its
# diodes already conduct), then let go; start angle {angle:g} deg (electrical); the profile's
# noise seed (verdicts checked over seeds 1-8). Written by rig/scenario/starts.py: edit that.
# The drive finds the magnet's angle and the speed from the back-EMF it measures in its first
# periods (above ~600 r/min: the catch), or from the back-EMF test (slower shafts), without a
# current beyond i_max and without a polarity error, then follows the profile: the speed
# held 0.3 s, then half of it.
description = "Flying start at {speed:+g} r/min: caught without a current spike, \
then {speed / 2:+g} r/min"
profile = "paper"
duration = 0.8
figure = "Starts"
tags = ["starts", "flying-start"]

[initial]
theta_e_deg = {angle:g}
speed_rpm = {speed:g}

[drive]
enable_at = 0.01

[limits]
i_max = {I_MAX}

[firmware]
soc_on_us = 8
soc_off_us = 1
soc_per_state = 5

# (a step, not a hold: a hold commands nothing, and the drive's reference stays 0)
[[speed]]
kind = "step"
to = {speed:g}
duration = 0.35

[[speed]]
kind = "ramp"
to = {speed / 2:g}
duration = 0.2

[[speed]]
kind = "hold"
duration = 0.25

[[load]]
at = 0.0
kind = "speed_hold"
speed = {speed:g}

[[load]]
at = {RELEASE:g}
kind = "step"
torque = 0

"""
    crits: list[str] = []
    crits.append(_crit("in RUN", "run_time_s", (0.01, "end"), comparison="report",
                       better="lower"))
    crits += _per_profile("current within i_max", "i_mag_max_a", (0.01, "end"),
                          dict.fromkeys(PROFILES, I_PEAK_FW if abs(speed) >= 2500 else I_PEAK),
                          name)
    crits.append(_crit("no polarity error", "polarity_loss_count", (0.03, "end"), limit=0,
                       comparison="=="))
    crits.append(_crit("stays in RUN", "fw_state_end", (0.03, "end"), limit=3, comparison="=="))
    crits += _regression(name, "speed after the catch (regression)", "speed_track_err_max_rpm",
                         (0.05, 0.35), 1.5, 20.0)
    # (FULL modulation's flux-carried loop rings at the electrical frequency after any
    # disturbance, decaying in ~0.1 s: after the catch at 2000 r/min on ideal 1.3-2.9 deg, after
    # a 1 N*m load step at 2000 r/min in steady running 1.2 deg; the usual limits from 0.2 s)
    crits += _regression(name, "position error after the catch (regression)", "pos_err_max_deg",
                         (0.03, 0.2), 1.25, 1.0)
    crits += _per_profile("position error", "pos_err_max_deg", (0.2, 0.35), POS_LIMIT, name)
    # (the ramp to half the speed and its end: on harsh the drive's own transient there, the
    # switch from FULL to linear modulation at 1350 r/min and the ramp's end at 1000 r/min,
    # reaches 5.9 deg in 1 seed of 8 with the catch long settled)
    crits += _regression(name, "position error through the ramp (regression)",
                         "pos_err_max_deg", (0.35, "end"), 1.25, 1.0, key="pos_err_max_deg@ramp")
    if name in ISR_COST:
        crits += _isr_cost(ISR_COST[name])
    return head + "\n".join(crits)


def files() -> dict[str, str]:
    out = {f"{n}.toml": load_start(n, t, a) for n, t, a in LOAD_STARTS}
    out.update({f"{n}.toml": flying(n, v, a) for n, v, a in FLYING})
    out["suites/starts.toml"] = suite()
    return out


def suite() -> str:
    lines = [
        "# Starts on a shaft that is not at rest (issue 24): a load already on it at the enable,",
        "# or a shaft still turning (flying start), on every fidelity profile. Written by",
        "# rig/scenario/starts.py (scenarios, criteria, regression limits, known failures).",
        'name = "starts"',
        'description = "Starts against a load on the shaft (torque within 20 ms, kick-back) and '
        'flying starts (-3000..3000 r/min), ideal/paper/harsh"',
        "scenarios = [",
    ]
    for n in [x[0] for x in LOAD_STARTS] + [x[0] for x in FLYING]:
        for p in PROFILES:
            why = NOT_IN_SUITE.get((n, p))
            lines.append(f'  # "{n}@{p}": not in the suite, {why}' if why else f'  "{n}@{p}",')
    lines.append("]")
    return "\n".join(lines) + "\n"


def main(argv: list[str]) -> int:
    check = "--check" in argv
    args = [a for a in argv if not a.startswith("--")]
    folder = Path(args[0]) if args else SCENARIO_DIR
    stale = write_generated(files(), folder, check)
    if stale:
        print("stale: " + ", ".join(stale) + " (run python -m rig.scenario.starts)")
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
