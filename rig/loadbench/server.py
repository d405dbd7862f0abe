"""The virtual load bench: a Modbus TCP server (pymodbus) in front of plant_rt's load machine.

Holding registers (setpoints) become LOAD_CMD frames on the bus, BENCH_TRUTH frames (speed,
shaft torque, load torque) become input registers; the register map is
protocols/modbus_load_bench.json. The server binds 127.0.0.1 by default.

Rules (the map's "exceptions" and "watchdog" sections):

* an address outside a table, a write to a read-only register or to part of a multi-register
  field: exception 2; a value out of range, not in the enumeration or not finite: exception
  3 (also a register count of 0 or above 125); a function code the map does not list
  (coils, discrete inputs, diagnostics, report server id, ...): exception 1; a setpoint
  that could not be sent, or a mode other than off while a fault is latched: exception 4.
  A refused write changes nothing.
* a write that changes the load (mode, torque, speed, k_speed) is sent as LOAD_CMD before
  the write is acknowledged, so a lockstep grant the client sends after the answer sees it.
* while the load is active the client refreshes the watchdog register (a new value) within
  watchdog_timeout_ms (wall clock) or the load is zeroed (mode off, torque 0) and the fault
  bit 'watchdog' latches until control.fault_reset.

``LoadBenchModel`` is the state machine (no I/O); ``serve()`` puts it on a bus and a socket.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import math
import os
import signal
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import can
from pymodbus.constants import ExcCodes
from pymodbus.pdu import ExceptionResponse, ModbusPDU
from pymodbus.pdu.decoders import DecodePDU
from pymodbus.server import ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice

from rig import bus as rigbus
from rig import protocols
from rig.bus.frames import FrameDecoder
from rig.loadbench.client import Field, RegisterMap, register_map

RPM_PER_RAD_S = 60.0 / (2.0 * math.pi)
MEASUREMENT_FRESH_S = 1.0
WATCHDOG_POLL_S = 0.02
LOAD_FIELDS = ("mode", "torque_setpoint", "speed_setpoint", "k_speed")


@dataclass(frozen=True)
class LoadCommand:
    """What LOAD_CMD carries (mode by its DBC name)."""

    mode: str
    torque: float
    speed: float
    k_speed: float


class SendFailed(RuntimeError):
    pass


Sender = Callable[[LoadCommand], None]


class LoadBenchModel:
    """Registers, validation, watchdog and faults of the load bench. Thread-safe."""

    def __init__(self, regmap: RegisterMap | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.map = regmap or register_map()
        self.clock = clock
        self._lock = threading.RLock()
        self.values: dict[str, float] = {f.name: f.default for f in self.map.holding.values()}
        self.values["map_version"] = float(self.map.version)
        self.faults: set[str] = set()
        self.expiries = 0
        self.wd_echo = 0
        self.wd_last = clock()
        self.cmd_seq = 0
        self.samples = 0
        self.sample_time: float | None = None
        self.speed_rpm = 0.0
        self.shaft_torque = 0.0
        self.load_torque = 0.0

    # -- images ------------------------------------------------------------------------
    def _image(self, table: str, values: dict[str, float]) -> list[int]:
        first, count = self.map.span(table)  # type: ignore[arg-type]
        regs = [0] * count
        for f in self.map.table(table).values():  # type: ignore[arg-type]
            regs[f.address - first:f.address - first + f.count] = f.encode(
                values.get(f.name, 0.0), self.map.word_order)
        return regs

    def holding_registers(self) -> list[int]:
        with self._lock:
            return self._image("holding", self.values)

    def input_registers(self) -> list[int]:
        with self._lock:
            return self._image("input", self._inputs())

    def _inputs(self) -> dict[str, float]:
        m = self.map
        active = self.active
        fresh = self.sample_time is not None and \
            self.clock() - self.sample_time < MEASUREMENT_FRESH_S
        sbits = m.input["status"].bits
        status = (active << sbits["load_active"]) | \
            ((self.mode_name == "speed_hold") << sbits["speed_hold"]) | \
            (active << sbits["watchdog_armed"]) | (fresh << sbits["measurement_valid"]) | \
            (bool(self.faults) << sbits["fault"])
        fbits = m.input["fault"].bits
        fault = sum(1 << fbits[name] for name in self.faults)
        return {"status": status, "fault": fault, "watchdog_echo": self.wd_echo,
                "watchdog_expiries": min(self.expiries, 65535), "command_seq": self.cmd_seq,
                "shaft_torque": self.shaft_torque, "speed": self.speed_rpm,
                "load_torque": self.load_torque, "sample_counter": self.samples % 2**32}

    # -- state -------------------------------------------------------------------------
    @property
    def mode_name(self) -> str:
        return self.map.mode_name(int(self.values["mode"]))

    @property
    def active(self) -> bool:
        return self.mode_name != "off"

    def command(self, values: dict[str, float] | None = None) -> LoadCommand:
        v = self.values if values is None else values
        mode = self.map.holding["mode"].enum_load_cmd[int(v["mode"])]
        return LoadCommand(mode, v["torque_setpoint"], v["speed_setpoint"], v["k_speed"])

    # -- writes ------------------------------------------------------------------------
    def write(self, address: int, regs: Sequence[int], send: Sender) -> tuple[int | None,
                                                                              list[int]]:
        """Validates and applies a holding-register write.

        Returns (Modbus exception code or None, the registers to store at ``address``)."""
        with self._lock:
            touched = self.map.fields_touched("holding", address, len(regs))
            for f in touched:
                if f.address < address or f.address + f.count > address + len(regs):
                    return int(ExcCodes.ILLEGAL_ADDRESS), list(regs)
                if f.access != "rw":
                    return int(ExcCodes.ILLEGAL_ADDRESS), list(regs)
            new = dict(self.values)
            for f in touched:
                lo = f.address - address
                value = float(f.decode(regs[lo:lo + f.count], self.map.word_order))
                if f.problem(value) is not None:
                    return int(ExcCodes.ILLEGAL_VALUE), list(regs)
                new[f.name] = value
            names = {f.name for f in touched}
            reset = "control" in names and int(new["control"]) & \
                (1 << self.map.holding["control"].bits["fault_reset"])
            new["control"] = 0.0  # command bits are self-clearing
            if reset:
                self.faults.clear()
            activating = self.map.mode_name(int(new["mode"])) != "off"
            if activating and self.faults and "mode" in names:
                return int(ExcCodes.DEVICE_FAILURE), list(regs)
            if "watchdog" in names and int(new["watchdog"]) != self.wd_echo:
                self.wd_echo = int(new["watchdog"])
                self.wd_last = self.clock()
            if activating and not self.active:
                self.wd_last = self.clock()  # activating the load counts as a refresh
            if any(new[n] != self.values[n] for n in LOAD_FIELDS):
                try:
                    self._send(send, self.command(new))
                except SendFailed:
                    self.faults.add("link")
                    return int(ExcCodes.DEVICE_FAILURE), list(regs)
            self.values = new
            stored = self._image("holding", self.values)
            lo = address - self.map.span("holding")[0]
            return None, stored[lo:lo + len(regs)]

    def _send(self, send: Sender, cmd: LoadCommand) -> None:
        self.cmd_seq = (self.cmd_seq + 1) % 256
        send(cmd)

    def tick(self, send: Sender) -> bool:
        """Watchdog: zeroes the load when the client went silent. True when it expired."""
        with self._lock:
            if not self.active:
                return False
            timeout = self.values["watchdog_timeout_ms"] / 1000.0
            if self.clock() - self.wd_last <= timeout:
                return False
            self.values["mode"] = float(self.map.mode_value("off"))
            self.values["torque_setpoint"] = 0.0
            self.faults.add("watchdog")
            self.expiries += 1
            try:
                self._send(send, self.command())
            except SendFailed:
                self.faults.add("link")
            return True

    def measurement(self, omega_m: float, t_shaft: float, tl: float) -> None:
        with self._lock:
            self.speed_rpm = omega_m * RPM_PER_RAD_S
            self.shaft_torque = t_shaft
            self.load_torque = tl
            self.samples += 1
            self.sample_time = self.clock()


# --------------------------------------------------------------------------------------
# The bus side


class BusSide:
    """LOAD_CMD out, BENCH_TRUTH in (validated by rig.bus.frames)."""

    def __init__(self, model: LoadBenchModel, transport: str | None, channel: str | None) -> None:
        self.model = model
        self.decoder = FrameDecoder(databases=("bench",))
        truth = protocols.database("bench").get_message_by_name("BENCH_TRUTH")
        self.bus = rigbus.open_bus(transport, channel,
                                   can_filters=[{"can_id": truth.frame_id, "can_mask": 0x7FF}])
        self._mode_values = protocols.choices("bench", "LOAD_CMD", "mode")
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._read, name="loadbench-bus", daemon=True)
        self._thread.start()

    def send(self, cmd: LoadCommand) -> None:
        try:
            frame = self.decoder.encode("LOAD_CMD", {
                "mode": self._mode_values[cmd.mode.lower()], "seq": self.model.cmd_seq,
                "torque": cmd.torque, "speed": cmd.speed, "k_speed": cmd.k_speed})
            self.bus.send(frame)
        except (can.CanError, OSError, ValueError, KeyError) as exc:
            raise SendFailed(str(exc)) from exc

    def _read(self) -> None:
        while not self._stop.is_set():
            try:
                msg = self.bus.recv(timeout=0.2)
            except (can.CanError, OSError):
                return
            if msg is None:
                continue
            d = self.decoder.decode(msg)
            if d is not None and d.name == "BENCH_TRUTH":
                s = d.signals
                self.model.measurement(float(s["omega_m"]), float(s["t_shaft"]), float(s["tl"]))

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=1.0)
        self.bus.shutdown()


# --------------------------------------------------------------------------------------
# The Modbus side


def _simdata(fields: Sequence[Field]) -> list[SimData]:
    out = []
    for f in fields:
        out.append(SimData(address=f.address, values=[0] * f.count,
                           datatype=DataType.REGISTERS, readonly=f.access != "rw"))
    return out


def device(model: LoadBenchModel, send: Sender) -> SimDevice:
    """The pymodbus device: holding and input tables of the map, validation by the model."""
    holding_first = model.map.span("holding")[0]
    input_first = model.map.span("input")[0]

    async def action(function_code: int, start_address: int, address: int, count: int,
                     registers: list[int], set_values: list[int] | list[bool] | None
                     ) -> ExcCodes | None:
        if function_code not in model.map.function_codes:  # (MapDecoder refuses them first)
            return ExcCodes.ILLEGAL_FUNCTION
        if function_code == 4:
            image = model.input_registers()
            registers[input_first - start_address:input_first - start_address + len(image)] = \
                image
            return None
        if set_values is None:
            image = model.holding_registers()
            lo = holding_first - start_address
            registers[lo:lo + len(image)] = image
            return None
        code, stored = model.write(address, [int(v) for v in set_values], send)
        if code is not None:
            return ExcCodes(code)
        set_values[:] = stored  # type: ignore[index,assignment]
        return None

    nothing = [SimData(address=0, values=[False] * 16, datatype=DataType.BITS)]
    return SimDevice(
        id=0,  # every unit id (a TCP server owns its socket)
        simdata=(nothing, list(nothing), _simdata(list(model.map.holding.values())),
                 _simdata(list(model.map.input.values()))),
        action=action,
    )


class _Refused(ModbusPDU):
    """A request answered with an exception before it reaches the device."""

    def __init__(self, function_code: int, code: ExcCodes) -> None:
        super().__init__()
        self.function_code = function_code
        self.code = code

    async def datastore_update(self, context: object, device_id: int) -> ModbusPDU:
        return ExceptionResponse(self.function_code, self.code)


class MapDecoder(DecodePDU):
    """Requests as the register map allows them: a function code not in its
    ``function_codes`` is exception 1 (the library would answer diagnostics, report server
    id, ... on its own); a known one the library cannot decode (a register count of 0 or
    above 125) is exception 3 with that function code (pymodbus sent a bare 0x80)."""

    def __init__(self, function_codes: Sequence[int]) -> None:
        super().__init__(True)
        self.allowed = frozenset(function_codes)

    def decode(self, frame: bytes) -> ModbusPDU | None:
        if not frame:
            return None
        fc = int(frame[0])
        if fc not in self.allowed:
            return _Refused(fc, ExcCodes.ILLEGAL_FUNCTION)
        pdu = super().decode(frame)
        return pdu if pdu is not None else _Refused(fc, ExcCodes.ILLEGAL_VALUE)


@dataclass
class ServeOptions:
    host: str = "127.0.0.1"
    port: int = 5020
    bus: str | None = None
    channel: str | None = None
    ready_file: Path | None = None
    watchdog_timeout_ms: int | None = None


async def _serve(opts: ServeOptions, stop: asyncio.Event) -> None:
    model = LoadBenchModel()
    if opts.watchdog_timeout_ms is not None:
        f = model.map.holding["watchdog_timeout_ms"]
        if f.problem(opts.watchdog_timeout_ms):
            raise ValueError(f.problem(opts.watchdog_timeout_ms))
        model.values["watchdog_timeout_ms"] = float(opts.watchdog_timeout_ms)
    side = BusSide(model, opts.bus, opts.channel)
    try:
        side.send(model.command())  # the load machine starts in the state the registers show
        server = ModbusTcpServer(device(model, side.send), address=(opts.host, opts.port))
        server.decoder = MapDecoder(model.map.function_codes)  # before any connection
        await server.serve_forever(background=True)
        sockets = getattr(server.transport, "sockets", None) or []
        if not sockets:
            raise OSError(f"cannot listen on {opts.host}:{opts.port}")
        host, port = sockets[0].getsockname()[:2]
        if opts.ready_file is not None:
            tmp = opts.ready_file.with_suffix(".tmp")
            tmp.write_text(json.dumps({"host": host, "port": port, "pid": os.getpid()}))
            tmp.replace(opts.ready_file)
        print(f"loadbench: Modbus TCP on {host}:{port}, bus {side.bus.channel_info}",
              flush=True)
        while not stop.is_set():
            model.tick(side.send)
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(stop.wait(), WATCHDOG_POLL_S)
        await server.shutdown()
    finally:
        with contextlib.suppress(SendFailed):
            model.values["mode"] = float(model.map.mode_value("off"))
            model.values["torque_setpoint"] = 0.0
            side.send(model.command())  # leave the load machine off
        side.close()


def serve(opts: ServeOptions) -> int:
    """Runs the server until SIGTERM/SIGINT; 0 on a clean stop."""
    if opts.host != "127.0.0.1":
        raise ValueError("the virtual load bench binds 127.0.0.1 only")

    async def main() -> None:
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGTERM, signal.SIGINT):
            loop.add_signal_handler(sig, stop.set)
        await _serve(opts, stop)

    asyncio.run(main())
    return 0
