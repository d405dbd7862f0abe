"""How many bits a classic CAN data or remote frame takes on the wire, its stuff bits counted
exactly (CAN 2.0 / ISO 11898-1): the bit clock of the fallback bus (``rig.bus.arbiter``)
holds the bus for this long. ``rig.bus.load.frame_bits`` is the worst case of the same.

The frame: start of frame (dominant, 0), the identifier (11 bits; or 11, SRR and IDE
recessive, then 18), RTR, IDE (0) and r0 for a base frame (r1 and r0 for an extended one), the
4-bit DLC, the data, the 15-bit CRC of all that. A stuff bit of the other level follows every
five equal bits in a row from the start of frame through the CRC, and counts towards the next
run; the CRC delimiter, the ACK slot and delimiter, the end of frame (7) and the intermission
(3) that follow are never stuffed.
"""

from __future__ import annotations

from rig.bus.load import UNSTUFFED_TAIL_BITS

CRC15_POLY = 0x4599  # x^15 + x^14 + x^10 + x^8 + x^7 + x^4 + x^3 + 1
STUFF_RUN = 5


def _bits(value: int, width: int) -> list[int]:
    return [(value >> (width - 1 - k)) & 1 for k in range(width)]


def crc15(bits: list[int]) -> int:
    crc = 0
    for b in bits:
        nxt = b ^ ((crc >> 14) & 1)
        crc = (crc << 1) & 0x7FFF
        if nxt:
            crc ^= CRC15_POLY
    return crc


def stuffed_part(can_id: int, data: bytes, *, extended: bool = False,
                 remote: bool = False, dlc: int | None = None) -> list[int]:
    """The bits from the start of frame through the CRC, before stuffing."""
    if len(data) > 8 or (remote and data):
        raise ValueError("a classic CAN frame carries 0 to 8 data bytes, a remote frame none")
    dlc = len(data) if dlc is None else dlc
    if extended:
        head = [0, *_bits(can_id >> 18, 11), 1, 1, *_bits(can_id & 0x3FFFF, 18),
                int(remote), 0, 0]
    else:
        head = [0, *_bits(can_id, 11), int(remote), 0, 0]
    bits = head + _bits(dlc, 4) + [b for byte in data for b in _bits(byte, 8)]
    return bits + _bits(crc15(bits), 15)


def stuff_bits(bits: list[int]) -> int:
    """How many stuff bits the sequence gets (each one starts the next run)."""
    count, run, last = 0, 0, None
    for b in bits:
        if b == last:
            run += 1
        else:
            last, run = b, 1
        if run == STUFF_RUN:
            count += 1
            last, run = 1 - b, 1  # the stuff bit, of the other level
    return count


def frame_bits(can_id: int, data: bytes, *, extended: bool = False,
               remote: bool = False) -> int:
    """The frame's length on the wire in bits, stuffing and the unstuffed tail included."""
    bits = stuffed_part(can_id, data, extended=extended, remote=remote)
    return len(bits) + stuff_bits(bits) + UNSTUFFED_TAIL_BITS
