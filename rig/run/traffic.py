"""Foreign traffic on a run's channel: frames that no node of the run sent.

Every message of the bench's protocols has one sender, its DBC transmitter (RIG: the rig;
PLANT: plant_rt; FW or DSP: fw_host). Every node counts the frames it sent and received per
identifier: the C programs in their exit counters (hilbus: ``tx_ids``, ``rx_ids``), the rig
on its link (and, on unixcan, every frame that reached its socket, filtered or not). A node
cannot receive more frames of a message than its sender sent: a surplus was sent by a node
outside the run (another run on the channel, a tool replaying a log, an attack), and so was
any frame of an identifier the run's nodes do not send, and any frame a node received of a
message it sends itself (no node receives its own frames, on either transport: the plant
that receives a BENCH_PROGRESS names a spoof even when the rig's own count of them is short
by a frame its full queue dropped). The run then fails as foreign
traffic (exit 3, the frames named): its data is not its own, and nothing is judged on it,
never a firmware failure. A node that only listens (``can.logger``, ``cantools monitor``)
sends nothing and changes nothing here.

The rig also sees at once a frame only the rig sends, and a BENCH_PROGRESS the plant cannot
have sent (``rig.link``): the run stops there. The counts catch the rest when the programs
have stopped (a program killed before its exit counters cannot be judged: its messages are
left out).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Mapping
from dataclasses import dataclass, field

from rig import protocols
from rig.bus import identity

KIND = "foreign_traffic"
NODES = {"RIG": "rig", "PLANT": "plant", "FW": "firmware", "DSP": "firmware"}
SHOWN = 6


def senders() -> dict[int, str]:
    """The node of the run that sends each message, by the message's whole identity (its
    id and format: ``rig.bus.identity``)."""
    return {identity.key(int(m.frame_id), extended=bool(m.is_extended_frame),
                         fd=bool(m.is_fd)): NODES[m.senders[0]]
            for db in ("drive", "vio", "bench") for m in protocols.database(db).messages
            if m.senders and m.senders[0] in NODES}


@dataclass
class Traffic:
    """Frames per identity (``rig.bus.identity``), sent and received, of the nodes whose
    counts are known."""

    sent: dict[str, Counter[int]] = field(default_factory=dict)
    received: dict[str, Counter[int]] = field(default_factory=dict)
    # frames a C program received of identifiers beyond those its exit counters list
    unlisted: dict[str, int] = field(default_factory=dict)

    def add_program(self, node: str, counters: Mapping[str, object]) -> None:
        """A C program's ``tx_ids`` / ``rx_ids`` (exit counters: {"<id>": frames, "other": n};
        hilbus counts standard data frames by their 11-bit identifier)."""
        for key, table in (("tx_ids", self.sent), ("rx_ids", self.received)):
            ids = counters.get(key)
            if not isinstance(ids, Mapping):
                continue
            counts: Counter[int] = Counter()
            for ident, n in ids.items():
                if str(ident).isdigit():
                    counts[identity.standard_key(int(ident))] += int(n)  # type: ignore[call-overload]
                elif key == "rx_ids":
                    self.unlisted[node] = int(n)  # type: ignore[call-overload]
            table[node] = counts

    def add_rig(self, sent: Mapping[int, int], received: Mapping[int, int]) -> None:
        """The rig's own counts, by the frames' whole identity (extended, remote and error
        frames and a frame of the other format, which no node of the run sends, kept apart:
        ``rig.bus.identity``)."""
        self.sent["rig"] = Counter(dict(sent))
        self.received["rig"] = Counter(dict(received))

    def surplus(self) -> list[tuple[int, str, int, int]]:
        """(frame id, receiving node, received, sent) wherever a node received more frames of
        an identifier than the run sent of it."""
        owner = senders()
        out = []
        for node, counts in self.received.items():
            for ident, got in counts.items():
                sender = owner.get(ident)
                if sender == node:
                    sent = 0  # no node receives its own frames: each one is another's
                elif sender is not None and sender not in self.sent:
                    continue  # its sender's counts are unknown: no judgement
                else:
                    sent = self.sent[sender].get(ident, 0) if sender is not None else 0
                if got > sent:
                    out.append((ident, node, got, sent))
        return sorted(out, key=lambda s: (s[3] - s[2], s[0], s[1]))

    def named_counters(self) -> dict[str, float]:
        """``<node>.tx.<MESSAGE>`` / ``<node>.rx.<MESSAGE>`` counters for result.json."""
        out: dict[str, float] = {}
        for way, table in (("tx", self.sent), ("rx", self.received)):
            for node, counts in table.items():
                for k, n in counts.items():
                    name = identity.name(k) or _counter_name(k)
                    out[f"{node}.{way}.{name}"] = out.get(f"{node}.{way}.{name}", 0.0) + n
        for node, n in self.unlisted.items():
            out[f"{node}.rx.other_ids"] = float(n)
        return out

    def problem(self, where: str) -> str | None:
        """The foreign-traffic failure message, or None when every count adds up."""
        lines = []
        for ident, node, got, sent in self.surplus():
            what = identity.describe(ident)
            by = senders().get(ident)
            lines.append(f"{what}: {node} received {got}, " + (
                "a message it sends itself" if by == node else
                f"the {by} sent {sent}" if by else "no node of the run sends it"))
        for node, n in self.unlisted.items():
            if n:
                lines.append(f"{node} received {n} frames of ids no node of the run sends")
        if not lines:
            return None
        more = f"; and {len(lines) - SHOWN} more" if len(lines) > SHOWN else ""
        return (f"foreign traffic on {where}: frames no node of the run sent: "
                + "; ".join(lines[:SHOWN]) + more + ". Another node sends on this channel "
                "(another run, a replay): the run's data is not its own and nothing is "
                "judged. Use a channel of its own (--channel NAME)")


def _counter_name(k: int) -> str:
    """A counter's name for a frame no DBC message is: ``0x11.ext.fd``, ``0x10.rtr.classic``."""
    parts = [f"0x{k & identity.ID_MASK:X}"]
    parts += [tag for tag, bit in (("ext", identity.EFF), ("rtr", identity.RTR),
                                   ("err", identity.ERR)) if k & bit]
    parts.append("fd" if k & identity.FD else "classic")
    return ".".join(parts)
