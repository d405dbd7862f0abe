"""The worst-case latency of each message on the lab's classic-CAN bus, from its DBC: the
response-time analysis of fixed-priority, non-preemptive CAN arbitration (the lower id wins,
a frame on the wire is never interrupted), as corrected by Davis, Burns, Bril and Lukkien
(2007, "Controller Area Network (CAN) schedulability analysis: refuted, revisited and
revised", section 3.2).

For a message m of transmission time C (its worst-case stuffed frame at the bit rate) and
period T, queued with no jitter: it may first wait for the one lower-priority frame already on
the wire (B, the longest of them); each higher-priority message k sends ceil((w + τ) / T_k)
frames while m waits w (τ: one bit time: a frame queued in the bit time before m starts still
wins). The queue may hold several of m's own instances in a busy period, so the analysis
takes each instance q of the level-m busy period t and keeps the worst:

    t    = B + sum over hp(m) and m of ceil(t / T_k) C_k
    w(q) = B + q C + sum over hp(m) of ceil((w(q) + τ) / T_k) C_k
    R    = max over q < ceil(t / T) of  w(q) - q T + C

On-demand messages (no ``GenMsgCycleTime``: parameters, limits) have no period to bound
their interference: they count as blocking (one on the wire), and get no latency of their
own. A message set whose higher-priority load reaches the bus is unschedulable: its busy
period never ends (None).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from fractions import Fraction

from rig.bus.load import MessageLoad

MAX_ITERATIONS = 100_000  # a fixed point further than this: the busy period does not end


@dataclass(frozen=True)
class Latency:
    name: str
    period_s: float
    worst_s: float | None  # None: unbounded (the bus is overloaded at this priority)

    @property
    def meets_period(self) -> bool:
        """Whether every frame is on the wire before the next one is queued."""
        return self.worst_s is not None and self.worst_s <= self.period_s


@dataclass(frozen=True)
class _Msg:
    """A message in bit times (integers: the analysis is exact, no rounding at a boundary)."""

    name: str
    c: int  # transmission time
    t: int | None  # period (None: on demand)


def _fixed_point(start: int, step: Callable[[int], int], limit: int) -> int | None:
    """Iterates x = step(x) from start until it settles; None past limit."""
    x = start
    for _ in range(MAX_ITERATIONS):
        nxt = step(x)
        if nxt > limit:
            return None
        if nxt == x:
            return x
        x = nxt
    return None


def _ceil_div(a: int, b: int) -> int:
    return -(-a // b)


def worst_case_latencies(loads: Sequence[MessageLoad], bitrate: int) -> list[Latency]:
    """Each cyclic message's worst-case response time (queued to received), by id. Periods
    must be whole bit times (a period in ms at a bit rate in kbit/s is)."""
    msgs = []
    for x in sorted(loads, key=lambda x: x.frame_id):
        period = None
        if x.cycle_ms:
            if (x.cycle_ms * bitrate) % 1000:
                raise ValueError(f"{x.name}: {x.cycle_ms} ms is not a whole number of bits at "
                                 f"{bitrate} bit/s")
            period = x.cycle_ms * bitrate // 1000
        msgs.append(_Msg(x.name, x.bits, period))
    out = []
    for i, m in enumerate(msgs):
        if m.t is None:
            continue
        period = m.t
        higher = [(k.c, k.t) for k in msgs[:i] if k.t is not None]
        blocking = max((k.c for k in msgs[i + 1:]), default=0)
        own = [*higher, (m.c, period)]
        # the level-m busy period at a load below 1 ends within (B + sum of C) / (1 - load):
        # no fixed point lies beyond; at a load of 1 or more there is none
        load_m = sum(Fraction(ck, tk) for ck, tk in own)
        limit = 2 * int((blocking + sum(ck for ck, _ in own)) / (1 - load_m)) + period \
            if load_m < 1 else -1  # (twice over: a cut-off, not a figure)
        t_busy = _fixed_point(
            m.c, lambda t, own=own, b=blocking: b + sum(_ceil_div(t, tk) * ck for ck, tk in own),
            limit)
        worst: int | None = None
        if t_busy is not None:
            worst = 0
            for q in range(_ceil_div(t_busy, period)):
                w = _fixed_point(
                    blocking + q * m.c,
                    lambda w, q=q, c=m.c, higher=higher, b=blocking: b + q * c + sum(
                        _ceil_div(w + 1, tk) * ck for ck, tk in higher),
                    limit)
                if w is None:
                    worst = None
                    break
                worst = max(worst, w - q * period + m.c)
        out.append(Latency(m.name, period / bitrate,
                           None if worst is None else worst / bitrate))
    return out
