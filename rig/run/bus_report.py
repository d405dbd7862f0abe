"""What the fallback bus (unixcan) did in a run, in words, for result.json's ``bus_report`` and
the report's "Bus": the other nodes on the run's channel, each a listener that may fall
behind (as on SocketCAN) with the frames it missed, and how the run's own nodes, which lose
no frame in lockstep, waited for each other.

Each sender counts the frames it dropped for each listener by the listener's socket name
(hilbus's exit counters ``listener_drops``, the rig's ``UnixCanBus.listener_drops``); the
rig names each node by its pid and command line when it sees it (``rig.bus.unixcan``).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from rig.bus import unixcan

SENDERS = ("plant", "firmware", "rig.bus")  # the counters' prefixes of the run's nodes


@dataclass
class BusNodes:
    """The other nodes of a unixcan channel over a run: socket name -> label in words."""

    start: dict[str, str] = field(default_factory=dict)
    end: dict[str, str] = field(default_factory=dict)
    lossless: bool = True  # lockstep: the run's own nodes lose no frame
    own_pids: dict[int, str] = field(default_factory=dict)  # the run's nodes: pid -> name
    can_log_node: str = ""  # the socket of the rig's own live capture (rig.bus.can_log)
    # each of the run's senders: the frames it dropped for each listener (socket name)
    drops: dict[str, dict[str, int]] = field(default_factory=dict)

    def add_drops(self, sender: str, drops: Any) -> None:
        if isinstance(drops, Mapping):
            self.drops[sender] = {str(k): int(v) for k, v in drops.items()
                                  if isinstance(v, int | float)}


def report(nodes: BusNodes, counters: Mapping[str, float]) -> dict[str, Any]:
    """``{"listeners": [...], "lockstep": {...}}`` (see the module's doc)."""
    sent = int(sum(counters.get(f"{s}.tx_frames", 0.0) for s in SENDERS))
    names = sorted(set(nodes.start) | set(nodes.end)
                   | {n for d in nodes.drops.values() for n in d})
    listeners, own = [], []
    for name in names:
        pid = unixcan.node_pid(name)
        if name == nodes.can_log_node:
            continue  # the rig's own log: can_log says what it missed
        if pid in nodes.own_pids:  # real time: the run's nodes are not lossless
            missed = sum(d.get(name, 0) for d in nodes.drops.values())
            own.append({"node": name, "program": nodes.own_pids[pid], "missed": missed})
            continue
        by_sender = {s: d[name] for s, d in nodes.drops.items() if d.get(name)}
        label = nodes.start.get(name) or nodes.end.get(name) or unixcan.node_label(name)
        listeners.append({
            "node": name, "pid": pid, "who": label,
            "at_start": name in nodes.start, "at_end": name in nodes.end,
            "missed": sum(by_sender.values()), "of_frames_sent": sent,
            "missed_by_sender": by_sender,
        })
    lockstep = {
        "waits": int(sum(counters.get(f"{s}.tx_stalls", 0.0) for s in SENDERS)),
        "wait_ms_total": round(sum(counters.get(f"{s}.tx_stall_ms_total", 0.0)
                                   for s in SENDERS), 3),
        "wait_ms_max": round(max((counters.get(f"{s}.tx_stall_ms_max", 0.0)
                                  for s in SENDERS), default=0.0), 3),
        "failures": int(sum(counters.get(f"{s}.tx_stall_failures", 0.0) for s in SENDERS)),
    }
    out: dict[str, Any] = {"listeners": listeners, "frames_sent": sent}
    if nodes.lossless:
        out["lockstep"] = lockstep
    else:
        out["own_drops"] = own
    return out


def can_log_missed(nodes: BusNodes) -> int:
    """The frames the senders dropped for the rig's own live capture (0 when lossless)."""
    return sum(d.get(nodes.can_log_node, 0) for d in nodes.drops.values())


def in_words(bus_report: Mapping[str, Any]) -> list[str]:
    """The report's lines: each listener and what it missed, the lockstep's waits, the rig's
    own live log of the bus."""
    lines = []
    for n in bus_report.get("listeners") or []:
        when = ("there at the start and the end" if n.get("at_start") and n.get("at_end") else
                "there at the start, gone by the end" if n.get("at_start") else
                "joined during the run" + (" and stayed" if n.get("at_end") else ""))
        missed = int(n.get("missed") or 0)
        what = (f"missed {missed:,} of the {int(n.get('of_frames_sent') or 0):,} frames the "
                "run's nodes sent (its queue stayed full: a listener may fall behind, as on "
                "SocketCAN)" if missed else "missed none of the frames the run's nodes sent")
        lines.append(f"- listener {n.get('who')} (`{n.get('node')}`), {when}: {what}")
    for n in bus_report.get("own_drops") or []:
        if n.get("missed"):
            lines.append(f"- in real time the run's own nodes are not lossless: "
                         f"{n.get('program')} missed {int(n['missed']):,} frames")
    lock = bus_report.get("lockstep") or {}
    if lock:
        failures = int(lock.get("failures") or 0)
        lines.append(
            f"- the run's own nodes (lockstep, lossless) lost no frame to each other: "
            f"{int(lock.get('waits') or 0):,} sends waited for a full node, "
            f"{float(lock.get('wait_ms_total') or 0):.1f} ms in all, the longest "
            f"{float(lock.get('wait_ms_max') or 0):.1f} ms"
            if not failures else
            f"- **{failures} send(s) of the run's own nodes gave up** after the bus's stall "
            "limit (a node of the run took no frame: see the failure)")
    log = bus_report.get("can_log") or {}
    if log:
        missed = log.get("missed")
        lines.append(
            f"- `{log.get('path')}`: a {log.get('kind')} of {int(log.get('frames') or 0):,} "
            f"frames: {log.get('detail')}; "
            + ("missed none" if missed == 0 else f"missed {missed:,}" if missed else
               "what it missed is not known")
            + ("" if log.get("kind_in_file") else " (the candump format has no room to say "
               "what kind of log it is: this report says it)")
            + (f"; **{log['error']}**" if log.get("error") else ""))
    return lines
