"""Faults as scenario data: the ``[[faults]]`` events of a scenario.

Each event starts at ``at`` (seconds, on a PWM period like every event) and lasts
``duration`` seconds, or to the end of the scenario. Who injects it:

- the plant (``FAULT_CMD`` of ``protocols/bench.dbc``, one fault slot per event, sent before
  the grant that starts on its period, and again with kind NONE where it ends): the physical
  faults (ADC channel offset, gain, stuck code, saturation; current sensor loss; an open
  phase; a gate that stays off; the DC link moving to a voltage) and the frame faults on the
  virtual-I/O wires between plant and firmware (VIO_PWM, VIO_ADC_x: loss, delay,
  corruption; ``plant_rt/include/plant_link.h``);
- the rig's own sender (``rig.link.frame_faults``): the frame faults on the drive-protocol frames it
  sends (DRIVE_CMD, DRIVE_LIMITS), and ``heartbeat_loss`` (no DRIVE_CMD at all).

Kinds, channels, phases and gates are the names of FAULT_CMD's value tables (lower case);
the messages and signals those of the DBC files. ``parse`` checks an event at load time and
reports every problem with its field (``rig.scenario`` adds the file and line).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, fields
from typing import Any, Protocol

from rig import protocols
from rig.scenario.numbers import shown

HEARTBEAT_LOSS = "heartbeat_loss"
TS = protocols.timebase().ts  # PWM period
FRAME_KINDS = ("frame_loss", "frame_delay", "frame_corrupt")
# the frames of the virtual I/O the plant's side of the wires handles (plant_link.h)
PLANT_MESSAGES = ("VIO_PWM", "VIO_ADC_0", "VIO_ADC_1", "VIO_ADC_2")
# the drive-protocol frames the rig sends in a run (rig.link.drive_master.DriveMaster)
RIG_MESSAGES = ("DRIVE_CMD", "DRIVE_LIMITS")

Path_ = tuple[str | int, ...]


class Checker(Protocol):
    """What ``parse`` needs of the scenario loader's checker (rig.scenario.schema.Checker)."""

    issues: list[Any]

    def err(self, path: Path_, message: str) -> None: ...

    def table(self, data: Any, path: Path_, allowed: Iterable[str]) -> dict[str, Any]: ...

    def number(self, data: Mapping[str, Any], path: Path_, key: str,
               default: float | None = None, *, minimum: float | None = None,
               maximum: float | None = None, positive: bool = False) -> float: ...

    def string(self, data: Mapping[str, Any], path: Path_, key: str,
               default: str | None = None, choices: Iterable[str] | None = None) -> str: ...


def _fault_cmd() -> Any:
    return protocols.database("bench").get_message_by_name("FAULT_CMD")


def choices(signal: str) -> dict[str, int]:
    """A FAULT_CMD value table, lower-case names (kind, channel, phase, gate)."""
    return protocols.choices("bench", "FAULT_CMD", signal)


def signal_range(signal: str) -> tuple[float, float]:
    sig = _fault_cmd().get_signal_by_name(signal)
    return float(sig.minimum), float(sig.maximum)


def kinds() -> tuple[str, ...]:
    """Every kind a scenario may name: FAULT_CMD's (but NONE) and the rig's own."""
    return (*(k for k in choices("kind") if k != "none"), HEARTBEAT_LOSS)


def plant_slots() -> int:
    """How many plant-side faults a scenario may hold (FAULT_CMD.slot's range)."""
    return int(signal_range("slot")[1]) + 1


def message_db(name: str) -> str | None:
    for db in protocols.DATABASES:
        try:
            protocols.database(db).get_message_by_name(name)
        except KeyError:
            continue
        return db
    return None


@dataclass(frozen=True)
class Corruption:
    """An XOR of a signal's raw bits as the 32-bit little-endian word at data byte ``byte``."""

    byte: int
    mask: int


def corruption(message: str, signal: str, xor: int) -> Corruption:
    """Where the raw bits ``xor`` of ``signal`` lie in ``message``'s data (from the DBC).
    ValueError when the signal is not little-endian or does not fit one 32-bit word."""
    db = message_db(message)
    if db is None:
        raise ValueError(f"no message {message!r} in protocols/")
    sig = protocols.database(db).get_message_by_name(message).get_signal_by_name(signal)
    if sig.byte_order != "little_endian":
        raise ValueError(f"{message}.{signal} is not little-endian")
    if xor <= 0 or xor >= 1 << sig.length:
        raise ValueError(f"xor must be a mask of {message}.{signal}'s {sig.length} raw bits "
                         f"(1 .. {(1 << sig.length) - 1}), not {shown(xor)}")
    byte, shift = divmod(int(sig.start), 8)
    if shift + sig.length > 32:
        raise ValueError(f"{message}.{signal} spans more than one 32-bit word")
    return Corruption(byte, xor << shift)


@dataclass(frozen=True)
class Fault:
    """One ``[[faults]]`` event (times in seconds; see the module docstring)."""

    kind: str
    at: float
    duration: float | None = None  # None: to the end of the scenario
    channel: str = ""
    phase: str = ""
    gate: str = ""
    value: float = 0.0
    ramp: float = 0.0
    message: str = ""
    delay: int = 0
    signal: str = ""
    xor: int = 0

    def to_json(self) -> dict[str, Any]:
        """The event as the scenario gave it (fields at their default left out)."""
        out: dict[str, Any] = {"kind": self.kind, "at": self.at}
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name not in out and v != f.default:
                out[f.name] = v
        return out

    @property
    def on_plant(self) -> bool:
        """Injected by the plant (FAULT_CMD), else by the rig's own sender."""
        return self.kind != HEARTBEAT_LOSS and not (
            self.kind in FRAME_KINDS and self.message in RIG_MESSAGES)

    def periods(self, n: int) -> tuple[int, int]:
        """[start, end) in periods of a scenario of n periods."""
        start = min(max(round(self.at / TS), 0), n)
        end = n if self.duration is None else min(round((self.at + self.duration) / TS), n)
        return start, end

    def fault_cmd(self, slot: int) -> dict[str, float | int]:
        """The FAULT_CMD signals that set this fault in ``slot`` (plant-side faults)."""
        values: dict[str, float | int] = {
            "slot": slot, "kind": choices("kind")[self.kind], "channel": 0, "phase": 0,
            "gate": 0, "message": 0, "seq": 0, "value": 0.0, "periods": 0, "delay": 0,
            "byte": 0, "xor": 0,
        }
        if self.channel:
            values["channel"] = choices("channel")[self.channel]
        if self.phase:
            values["phase"] = choices("phase")[self.phase]
        if self.gate:
            values["gate"] = choices("gate")[self.gate]
        if self.kind in FRAME_KINDS:
            db = message_db(self.message)
            assert db is not None
            values["message"] = protocols.database(db).get_message_by_name(
                self.message).frame_id
        values["value"] = self.value
        values["periods"] = round(self.ramp / TS)
        values["delay"] = self.delay
        if self.kind == "frame_corrupt":
            c = corruption(self.message, self.signal, self.xor)
            values["byte"], values["xor"] = c.byte, c.mask
        return values

    @staticmethod
    def clear_cmd(slot: int) -> dict[str, float | int]:
        """The FAULT_CMD signals that free ``slot``."""
        return {"slot": slot, "kind": choices("kind")["none"], "channel": 0, "phase": 0,
                "gate": 0, "message": 0, "seq": 0, "value": 0.0, "periods": 0, "delay": 0,
                "byte": 0, "xor": 0}


# --------------------------------------------------------------------------------------
# Load-time checks

FIELDS = ("at", "duration", "kind", "channel", "phase", "gate", "value", "code", "ramp",
          "message", "delay", "signal", "xor")
# what each kind needs besides at/duration (the rest is an error)
_NEEDS: dict[str, tuple[str, ...]] = {
    "adc_offset": ("channel", "value"),
    "adc_gain": ("channel", "value"),
    "adc_stuck": ("channel", "code"),
    "adc_saturation": ("channel", "value"),
    "sensor_loss": ("channel",),
    "open_phase": ("phase",),
    "gate_off": ("phase", "gate"),
    "dc_link": ("value", "ramp"),
    "frame_loss": ("message",),
    "frame_delay": ("message", "delay"),
    "frame_corrupt": ("message", "signal", "xor"),
    HEARTBEAT_LOSS: (),
}
_OPTIONAL = {"ramp"}


def _integer(c: Checker, d: Mapping[str, Any], path: Path_, key: str, lo: int,
             hi: int) -> int:
    v = d.get(key)
    if isinstance(v, bool) or not isinstance(v, int):
        c.err((*path, key), f"must be an integer, not {shown(v)}")
        return lo
    if not lo <= v <= hi:
        c.err((*path, key), f"must be in {lo} .. {hi}, not {shown(v)}")
        return lo
    return v


def parse(c: Checker, raw: Any, path: Path_, duration: float,
          adc_bits: Mapping[str, int]) -> Fault | None:
    """One ``[[faults]]`` table; None after reporting its problems. ``adc_bits``: the
    converter resolution per channel on the scenario's profile (a stuck code must exist)."""
    d = c.table(raw, path, FIELDS)
    if not d:
        return None
    n_issues = len(c.issues)
    kind = c.string(d, path, "kind", choices=kinds())
    at = c.number(d, path, "at", minimum=0.0)
    if at >= duration > 0:
        c.err((*path, "at"), f"{at:g} s is not before the end of the scenario ({duration:g} s)")
    dur: float | None = None
    if "duration" in d:
        dur = c.number(d, path, "duration", positive=True)
        if at + dur > duration + 1e-9:
            c.err((*path, "duration"), f"the fault would end at {at + dur:g} s, after the end "
                                       f"of the scenario ({duration:g} s); leave duration out "
                                       "to keep it to the end")
        elif dur < TS - 1e-12:
            c.err((*path, "duration"), f"must last at least one PWM period ({TS:g} s)")
    if not kind:
        return None
    needs = _NEEDS[kind]
    for key in d:
        if key not in ("at", "duration", "kind") and key not in needs:
            c.err((*path, key), f"not a field of a {kind} fault (its fields: "
                                f"{', '.join(('at', 'duration', 'kind', *needs))})")
    for key in needs:
        if key not in d and key not in _OPTIONAL:
            c.err((*path, key), f"a {kind} fault needs {key}")
    f = Fault(kind=kind, at=at, duration=dur)
    fields: dict[str, Any] = {}
    lo, hi = signal_range("value")
    if "channel" in needs and "channel" in d:
        allowed = [x for x in choices("channel") if kind != "sensor_loss" or x != "vdc"]
        fields["channel"] = c.string(d, path, "channel", choices=allowed)
    if "phase" in needs and "phase" in d:
        fields["phase"] = c.string(d, path, "phase", choices=choices("phase"))
    if "gate" in needs and "gate" in d:
        fields["gate"] = c.string(d, path, "gate", choices=choices("gate"))
    if "value" in needs and "value" in d:
        positive = kind in ("adc_saturation", "dc_link")
        minimum = 0.0 if kind == "adc_gain" else lo
        fields["value"] = c.number(d, path, "value", minimum=minimum, maximum=hi,
                                   positive=positive)
    if kind == "adc_stuck" and "code" in d:
        channel = fields.get("channel", "")
        bits = adc_bits.get(channel)
        top = (1 << bits) - 1 if bits else int(hi)
        fields["value"] = float(_integer(c, d, path, "code", 0, top))
    if kind == "dc_link":
        ramp = c.number(d, path, "ramp", 0.0, minimum=0.0)
        p_max = signal_range("periods")[1]
        if round(ramp / TS) > p_max:
            c.err((*path, "ramp"), f"at most {p_max * TS:g} s ({p_max:g} periods)")
        fields["ramp"] = ramp
    if "message" in needs and "message" in d:
        allowed = PLANT_MESSAGES + RIG_MESSAGES
        name = d["message"]
        if not isinstance(name, str) or name not in allowed:
            c.err((*path, "message"), f"{name!r} is not one of: {', '.join(allowed)}")
        else:
            fields["message"] = name
    if kind == "frame_delay" and "delay" in d:
        lo_d, hi_d = signal_range("delay")
        fields["delay"] = _integer(c, d, path, "delay", max(1, int(lo_d)), int(hi_d))
    if kind == "frame_corrupt" and "signal" in d and "xor" in d and "message" in fields:
        sig = c.string(d, path, "signal")
        xor = d["xor"]
        if isinstance(xor, bool) or not isinstance(xor, int):
            c.err((*path, "xor"), f"must be an integer mask, not {shown(xor)}")
        elif sig:
            try:
                cor = corruption(fields["message"], sig, xor)
            except KeyError:
                c.err((*path, "signal"), f"{fields['message']} has no signal {sig!r}")
            except ValueError as exc:
                c.err((*path, "xor"), str(exc))
            else:
                if fields["message"] in PLANT_MESSAGES and cor.byte > signal_range("byte")[1]:
                    c.err((*path, "signal"), f"lies beyond data byte "
                                             f"{signal_range('byte')[1]:g} (FAULT_CMD.byte)")
                fields["signal"], fields["xor"] = sig, xor
    if kind == HEARTBEAT_LOSS and "message" in d:
        c.err((*path, "message"), "a heartbeat loss is the loss of DRIVE_CMD: no message")
    if len(c.issues) > n_issues:
        return None
    return Fault(**{**f.__dict__, **fields})


def check_all(c: Checker, faults: list[Fault], path: Path_) -> None:
    """Rules across the events: the plant's fault slots."""
    on_plant = [f for f in faults if f.on_plant]
    if len(on_plant) > plant_slots():
        c.err(path, f"{len(on_plant)} plant-side faults: at most {plant_slots()} "
                    "(FAULT_CMD.slot)")


def adc_bits_of(values: Mapping[str, Any]) -> dict[str, int]:
    """The converter resolution per FAULT_CMD channel from profile values (``adc.bits``,
    ``adc.vdc_bits``)."""
    out: dict[str, int] = {}
    cur, vdc = values.get("adc.bits"), values.get("adc.vdc_bits")
    for ch in choices("channel"):
        v = vdc if ch == "vdc" else cur
        if isinstance(v, int | float) and not isinstance(v, bool) and 0 < v <= 64:
            out[ch] = int(v)
    return out
