"""The bus load of a classic-CAN message set, from its DBC: each cyclic message's frame in
bits with worst-case bit stuffing, times its rate (``GenMsgCycleTime``), over the bit rate
(the database attribute ``Baudrate``: the drive's eCAN runs classic CAN at 1 Mbit/s).

Worst-case frame length (a data frame, CAN 2.0): the stuffed part is SOF, arbitration,
control, data and CRC (34 bits plus 8 per data byte with an 11-bit id, 54 with a 29-bit id),
at most one stuff bit per 4 after the first; then CRC delimiter, ACK slot and delimiter, end
of frame and intermission (13 bits) are never stuffed.
"""

from __future__ import annotations

from dataclasses import dataclass

from rig import protocols

STUFFED_HEADER_BITS = {False: 34, True: 54}  # 11-bit id / 29-bit id, before the data
UNSTUFFED_TAIL_BITS = 13  # CRC delimiter, ACK slot, ACK delimiter, EOF (7), intermission (3)
TELEMETRY_LIMIT_PCT = 60.0  # the default telemetry's share of the bus (issue 37)


def frame_bits(data_bytes: int, extended: bool = False) -> int:
    """Bits of a classic-CAN data frame with ``data_bytes`` of data, worst-case stuffing."""
    if not 0 <= data_bytes <= 8:
        raise ValueError(f"classic CAN carries 0 … 8 data bytes, not {data_bytes}")
    stuffed = STUFFED_HEADER_BITS[extended] + 8 * data_bytes
    return stuffed + (stuffed - 1) // 4 + UNSTUFFED_TAIL_BITS


@dataclass(frozen=True)
class MessageLoad:
    name: str
    frame_id: int
    sender: str
    length: int
    cycle_ms: int | None  # None: sent on demand (not counted)
    bits: int

    @property
    def per_s(self) -> float:
        return 0.0 if not self.cycle_ms else 1000.0 / self.cycle_ms

    def pct(self, bitrate: int) -> float:
        return 100.0 * self.bits * self.per_s / bitrate


def bitrate(db: str = "drive") -> int:
    """The bit rate the database names (its ``Baudrate`` attribute)."""
    dbc = protocols.database(db).dbc
    attr = dbc.attributes.get("Baudrate") if dbc is not None else None
    if attr is None or not isinstance(attr.value, int):
        raise ValueError(f"protocols/{db}.dbc: database attribute Baudrate missing")
    return attr.value


def message_loads(db: str = "drive") -> list[MessageLoad]:
    """Every message of a classic-CAN database, by id."""
    out = []
    for m in sorted(protocols.database(db).messages, key=lambda m: m.frame_id):
        if m.is_fd:
            raise ValueError(f"protocols/{db}.dbc: {m.name} is CAN FD, not classic CAN")
        out.append(MessageLoad(m.name, m.frame_id, ",".join(m.senders), m.length,
                               m.cycle_time or None, frame_bits(m.length, m.is_extended_frame)))
    return out


def total_pct(loads: list[MessageLoad], rate: int) -> float:
    return sum(x.pct(rate) for x in loads)


def table(db: str = "drive") -> str:
    """The load table as text, with each cyclic message's worst-case latency
    (``rig.bus.latency``)."""
    from rig.bus import latency

    rate = bitrate(db)
    loads = message_loads(db)
    worst = {x.name: x.worst_s for x in latency.worst_case_latencies(loads, rate)}
    lines = [f"protocols/{db}.dbc at {rate / 1e6:g} Mbit/s, classic CAN, worst-case stuffing",
             f"{'message':14s} {'id':>6s} {'sender':7s} {'DLC':>3s} {'bits':>5s} "
             f"{'per s':>7s} {'load %':>7s} {'worst latency':>13s}"]
    for x in loads:
        per_s = f"{x.per_s:7g}" if x.cycle_ms else "   (on demand)"
        load = f"{x.pct(rate):7.2f}" if x.cycle_ms else ""
        late = ""
        if x.name in worst:
            w = worst[x.name]
            late = "     unbounded" if w is None else f"{w * 1e6:9.0f} µs"
        lines.append(f"{x.name:14s} {x.frame_id:#6x} {x.sender:7s} {x.length:3d} {x.bits:5d} "
                     f"{per_s} {load}{late}".rstrip())
    lines.append(f"{'cyclic total':14s} {'':>6s} {'':7s} {'':>3s} {'':>5s} {'':>7s} "
                 f"{total_pct(loads, rate):7.2f}")
    return "\n".join(lines)
