"""Driver for the Arduino Uno actuator controller (firmware in ``rig/hw/firmware``).

Two layers, kept apart as in pyserial's own design:

* **protocol** -- :class:`Protocol`, :class:`LineSplitter`, :class:`Frame`,
  :class:`Status`: pure functions that encode and decode the line protocol
  of ``rig/hw/firmware/PROTOCOL.md`` (``$<seq>,<CMD>[,<arg>...]*<XOR hex>\\n``).
  No I/O; unit-testable without hardware.
* **transport / driver** -- :class:`ArduinoActuator`: opens the port with
  :func:`serial.serial_for_url` (so ``/dev/ttyACM0``, ``/dev/pts/N`` from the
  emulator and ``socket://host:port`` all work), runs a reader thread that
  matches replies to requests by sequence number, does the ready handshake
  (also after an MCU reset), sends a heartbeat from a background thread while
  connected (the firmware stops the motors when it has not heard a valid
  frame for 100 ms), and bounds every command by a timeout with retries.
  Errors are one-line exceptions naming the port and the command.
* **link clock** -- :class:`LinkClock`: the time base of the timeouts.  A
  real controller (``/dev/ttyACM0``, ``socket://``) runs in real time and so
  does the driver: :class:`LinkClock` is ``time.monotonic()``.  The emulator
  (``rig/hw/sim``) runs the firmware in *simulated* time, which drifts from the
  wall clock whenever the OS does not schedule the emulator or this process
  on time.  For a pty served by ``ctr_sim`` the driver therefore attaches an
  :class:`EmulatorClock`: every heartbeat also leases the emulator a bounded
  amount of simulated time (so a host thread that runs late freezes the
  simulation instead of tripping the firmware's 100 ms link watchdog), and
  the command / homing / settle timeouts are counted in simulated time.
"""

from __future__ import annotations

import itertools
import logging
import math
import os
import re
import socket
import stat
import threading
import time
from dataclasses import dataclass, field
from typing import Callable

import serial

from rig.hw.actuator import (
    JOINTS,
    Actuator,
    ActuatorError,
    ActuatorResetError,
    FirmwareError,
    JointValues,
    LinkError,
    SoftLimits,
)

__all__ = [
    "PROTO_VERSION",
    "ERROR_NAMES",
    "ProtocolError",
    "Frame",
    "Status",
    "Protocol",
    "LineSplitter",
    "LinkClock",
    "EmulatorClock",
    "ArduinoActuator",
]

log = logging.getLogger(__name__)

# ---------------------------------------------------------------------------
# protocol (pure)
# ---------------------------------------------------------------------------

PROTO_VERSION = 1
#: bytes between '$' and '\n' the firmware accepts
LINE_MAX = 64

#: firmware error codes (``$<seq>,ERR,<code>,<name>``)
ERROR_NAMES = {
    1: "BADCS",      # checksum mismatch
    2: "SYNTAX",     # malformed frame
    3: "UNKNOWN",    # unknown command
    4: "LIMIT",      # target outside the soft limits
    5: "NOTHOMED",   # MOV before HOME completed
    6: "BUSY",       # homing in progress
    7: "TRUNC",      # frame cut short or too long
    8: "BADARG",     # wrong number / range of arguments
}
#: errors caused by a damaged frame: the command is retried
RETRYABLE_ERRORS = frozenset({1, 2, 7})

# STAT flag bits
F_HOMED = 0x001
F_HOMING = 0x002
F_ENABLED = 0x004
F_SETTLED0 = 0x008
F_SETTLED1 = 0x010
F_WDOG = 0x020
F_SWITCH = 0x040
F_ENCERR = 0x080
F_HOMEFAIL = 0x100


_CMD_RE = re.compile(r"[A-Z0-9]{1,7}")


class ProtocolError(ValueError):
    """A line that is not a valid frame."""


@dataclass(frozen=True)
class Frame:
    """A decoded frame: sequence number, kind (command or reply) and fields."""

    seq: int
    kind: str
    args: tuple[str, ...] = ()

    def int_arg(self, i: int, base: int = 10) -> int:
        try:
            return int(self.args[i], base)
        except (IndexError, ValueError):
            raise ProtocolError(f"{self.kind} frame: field {i} is not an integer: {self.args!r}") from None


@dataclass(frozen=True)
class Status:
    """Decoded ``STAT`` frame."""

    position: JointValues
    flags: int
    t: float = field(default=0.0, compare=False)   # time.monotonic() of receipt

    homed = property(lambda self: bool(self.flags & F_HOMED))
    homing = property(lambda self: bool(self.flags & F_HOMING))
    enabled = property(lambda self: bool(self.flags & F_ENABLED))
    watchdog_tripped = property(lambda self: bool(self.flags & F_WDOG))
    home_switch = property(lambda self: bool(self.flags & F_SWITCH))
    encoder_error = property(lambda self: bool(self.flags & F_ENCERR))
    home_failed = property(lambda self: bool(self.flags & F_HOMEFAIL))

    @property
    def settled(self) -> tuple[bool, bool]:
        return bool(self.flags & F_SETTLED0), bool(self.flags & F_SETTLED1)


class Protocol:
    """Encoding / decoding of the line protocol (pure functions).

    Wire units are integers: micrometres for ``insertion_mm`` and
    millidegrees for ``rotation_deg``.
    """

    @staticmethod
    def checksum(body: bytes) -> int:
        """XOR of the bytes between '$' and '*'."""
        c = 0
        for b in body:
            c ^= b
        return c

    @staticmethod
    def encode(seq: int, cmd: str, *args: int | str) -> bytes:
        if not 0 <= seq <= 65535:
            raise ValueError(f"sequence number out of range: {seq}")
        if not _CMD_RE.fullmatch(cmd):
            raise ValueError(f"bad command name: {cmd!r} (1-7 of A-Z, 0-9)")
        parts = [str(seq), cmd]
        for a in args:
            if isinstance(a, bool) or not isinstance(a, (int, str)):
                raise ValueError(f"{cmd}: argument must be int or str, got {a!r}")
            s = str(a)
            if any(c in s for c in ",*$\r\n") or not s.isascii():
                raise ValueError(f"{cmd}: argument contains a reserved character: {s!r}")
            parts.append(s)
        body = ",".join(parts).encode("ascii")
        if len(body) + 3 > LINE_MAX:
            raise ValueError(f"{cmd}: frame longer than {LINE_MAX} bytes")
        return b"$" + body + b"*%02X\n" % Protocol.checksum(body)

    @staticmethod
    def decode(line: bytes) -> Frame:
        """Decode one line (with or without the trailing newline)."""
        line = line.rstrip(b"\r\n")
        if not line.startswith(b"$"):
            raise ProtocolError(f"frame does not start with '$': {line[:40]!r}")
        star = line.rfind(b"*")
        if star < 0 or len(line) - star != 3:
            raise ProtocolError(f"missing '*HH' checksum: {line[:40]!r}")
        body = line[1:star]
        try:
            cs = int(line[star + 1:], 16)
        except ValueError:
            raise ProtocolError(f"bad checksum digits: {line[:40]!r}") from None
        if Protocol.checksum(body) != cs:
            raise ProtocolError(f"checksum mismatch (got {cs:02X}, computed "
                                f"{Protocol.checksum(body):02X}): {line[:40]!r}")
        try:
            text = body.decode("ascii")
        except UnicodeDecodeError:
            raise ProtocolError(f"non-ASCII frame: {line[:40]!r}") from None
        parts = text.split(",")
        if len(parts) < 2 or not parts[0].isdigit() or not parts[1]:
            raise ProtocolError(f"malformed frame: {text!r}")
        seq = int(parts[0])
        if seq > 65535:
            raise ProtocolError(f"sequence number out of range: {text!r}")
        return Frame(seq, parts[1], tuple(parts[2:]))

    # -- units -----------------------------------------------------------
    @staticmethod
    def to_wire(v: JointValues) -> tuple[int, int]:
        return (round(v.insertion_mm * 1000), round(v.rotation_deg * 1000))

    @staticmethod
    def from_wire(um: int, mdeg: int) -> JointValues:
        return JointValues(um / 1000.0, mdeg / 1000.0)

    @staticmethod
    def limits_to_wire(limits: SoftLimits) -> list[tuple[int, int, int]]:
        """``LIM`` arguments (joint, min, max), rounded inwards so that the
        firmware range never exceeds the host range."""
        out = []
        for j, name in enumerate(JOINTS):
            lo, hi = getattr(limits, name)
            out.append((j, math.ceil(round(lo * 1000, 6)), math.floor(round(hi * 1000, 6))))
        return out

    @staticmethod
    def parse_stat(frame: Frame, t: float = 0.0) -> Status:
        if frame.kind != "STAT" or len(frame.args) != 3:
            raise ProtocolError(f"not a STAT frame: {frame!r}")
        pos = Protocol.from_wire(frame.int_arg(0), frame.int_arg(1))
        return Status(pos, frame.int_arg(2, 16), t)

    @staticmethod
    def error_of(frame: Frame) -> tuple[int, str]:
        """(code, name) of an ERR frame."""
        code = frame.int_arg(0)
        name = frame.args[1] if len(frame.args) > 1 else ERROR_NAMES.get(code, "?")
        return code, name


class LineSplitter:
    """Incremental splitter: bytes in, complete ``$...`` lines out.

    Bytes before a '$' are noise and dropped; a line longer than ``max_len``
    is dropped (counted in :attr:`dropped`).
    """

    def __init__(self, max_len: int = 4 * LINE_MAX):
        self.max_len = max_len
        self._buf = bytearray()
        self.dropped = 0

    def feed(self, data: bytes) -> list[bytes]:
        out = []
        self._buf += data
        while True:
            nl = self._buf.find(b"\n")
            if nl < 0:
                break
            line = bytes(self._buf[:nl])
            del self._buf[:nl + 1]
            d = line.rfind(b"$")
            if d < 0:
                if line.strip():
                    self.dropped += 1
                continue
            if d > 0:
                self.dropped += 1
            out.append(line[d:])
        if len(self._buf) > self.max_len:
            self.dropped += 1
            d = self._buf.rfind(b"$")
            del self._buf[:d if d > 0 else len(self._buf)]
        return out


# ---------------------------------------------------------------------------
# link clock
# ---------------------------------------------------------------------------

#: emulator clock: when the emulator's simulated time has not advanced for this
#: long of wall-clock time although the emulator is not waiting for this host
#: (it is stopped, e.g. SIGSTOP, or hung), waits count wall-clock time from
#: then on, so that every wait stays bounded
EMULATOR_STALL_S = 2.0
#: abstract unix socket of ctr_sim's clock channel: "@ctr_sim:<pty path>"
EMULATOR_SOCKET_PREFIX = "ctr_sim:"


class LinkClock:
    """Time base of a link, in seconds: the controller's time.

    The base class is real time (``time.monotonic()``), the clock of a real
    controller.  :meth:`wait` waits for an event at most ``timeout_s`` of link
    time; :meth:`tick` is called by the heartbeat thread after each heartbeat
    with the number of bytes written to the port so far.
    """

    emulated = False

    def now(self) -> float:
        return time.monotonic()

    def wait(self, event: threading.Event, timeout_s: float) -> bool:
        return event.wait(max(0.0, timeout_s))

    def tick(self, bytes_written: int) -> None:
        pass

    def close(self) -> None:
        pass

    def describe(self) -> str:
        return "real time"


class EmulatorClock(LinkClock):
    """Simulated time of a ``ctr_sim`` emulator, over its clock channel.

    The channel is the abstract unix socket ``@ctr_sim:<pty>`` (SOCK_SEQPACKET)
    that the emulator opens next to its pty; see ``rig/hw/firmware/README.md``.

    * :meth:`tick` sends a lease ``L <bytes written>``: the emulator may run
      ``lease_s`` (50 ms) of simulated time past the moment it has read those
      bytes -- the heartbeat just written among them.  So the firmware sees a
      heartbeat at least every 50 ms of its own time, however late the OS runs
      the heartbeat thread; the simulation waits for a late host instead.
    * :meth:`now` is the emulator's simulated time (reported every 10 ms of it),
      so timeouts mean the same to the host and to the firmware.  When the
      emulator's time stands still although it is not waiting for this host,
      wall-clock time beyond ``stall_s`` (:data:`EMULATOR_STALL_S`) counts too; when the
      channel closes (emulator gone) the clock continues in wall-clock time.
    """

    emulated = True

    def __init__(self, sock: socket.socket, port: str, pid: int, lease_s: float, sim_s: float):
        self._sock = sock
        self.port = port
        self.pid = pid
        self.lease_s = lease_s
        self.stall_s = EMULATOR_STALL_S    # see EMULATOR_STALL_S
        self._lock = threading.Lock()
        self._sim_s = sim_s
        self._offset_s = 0.0               # wall time counted while the emulator stood still
        self._last_advance = time.monotonic()
        self._waiting = False              # the emulator waits for our next lease
        self._closed_at: float | None = None
        self._closed_base = 0.0
        self.leases = 0                    # leases sent
        self.waits_seen = 0                # times the emulator waited for this host

    @classmethod
    def attach(cls, url: str, timeout_s: float = 3.0) -> "EmulatorClock | None":
        """The clock channel of the emulator serving ``url``, or None when ``url``
        is not a pty of a running ``ctr_sim`` (a real port, ``socket://``, an
        emulator started with ``--no-sync``)."""
        if "://" in url or not hasattr(socket, "AF_UNIX") or not hasattr(socket, "SOCK_SEQPACKET"):
            return None
        try:
            path = os.path.realpath(url)
            st = os.stat(path)
        except OSError:
            return None
        if not stat.S_ISCHR(st.st_mode):
            return None
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        try:
            sock.connect("\0" + EMULATOR_SOCKET_PREFIX + path)
        except OSError:
            sock.close()
            return None
        try:
            sock.settimeout(timeout_s)
            hello = sock.recv(256).decode("ascii", "replace").split()
            if len(hello) < 7 or hello[0] != "H":
                raise ValueError(f"unexpected hello {hello!r}")
            pid, dev, rdev, ino, lease_us, us = (int(x) for x in hello[1:7])
            if (dev, rdev, ino) != (st.st_dev, st.st_rdev, st.st_ino):
                raise ValueError(f"the emulator (pid {pid}) serves another pty than {path}")
            sock.setblocking(False)
        except (OSError, ValueError) as e:
            sock.close()
            log.warning("%s: emulator clock channel unusable (%s): using real time", url, e)
            return None
        return cls(sock, url, pid, lease_us / 1e6, us / 1e6)

    # -- reports -----------------------------------------------------------
    def _drain(self) -> None:
        """Read the emulator's reports (caller holds the lock)."""
        while self._closed_at is None:
            try:
                msg = self._sock.recv(128)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                msg = b""
            if not msg:
                self._close_locked()
                return
            parts = msg.split()
            if len(parts) < 2 or not parts[1].isdigit():
                continue
            t = int(parts[1]) / 1e6
            if parts[0] == b"T":
                real = time.monotonic()
                if not self._waiting:
                    self._offset_s += max(0.0, real - self._last_advance - self.stall_s)
                self._sim_s = max(self._sim_s, t)
                self._last_advance = real
                self._waiting = False
            elif parts[0] == b"W":
                self._sim_s = max(self._sim_s, t)
                self._waiting = True
                self.waits_seen += 1

    def _now_locked(self) -> float:
        real = time.monotonic()
        if self._closed_at is not None:
            return self._closed_base + (real - self._closed_at)
        frozen = 0.0 if self._waiting else max(0.0, real - self._last_advance - self.stall_s)
        return self._sim_s + self._offset_s + frozen

    def _close_locked(self) -> None:
        if self._closed_at is None:
            self._closed_base = self._now_locked()
            self._closed_at = time.monotonic()
            try:
                self._sock.close()
            except OSError:         # pragma: no cover
                pass

    # -- LinkClock -----------------------------------------------------------
    def now(self) -> float:
        with self._lock:
            self._drain()
            return self._now_locked()

    def wait(self, event: threading.Event, timeout_s: float) -> bool:
        end = self.now() + timeout_s
        while True:
            left = end - self.now()
            if left <= 0:
                return event.is_set()
            # simulated time runs at most at wall-clock speed (ctr_sim --speed 1):
            # waiting ``left`` of wall time cannot overshoot by more than the 50 ms slice
            if event.wait(min(left, 0.05)):
                return True

    def tick(self, bytes_written: int) -> None:
        with self._lock:
            if self._closed_at is not None:
                return
            try:
                self._sock.send(b"L %d" % bytes_written, socket.MSG_DONTWAIT)
                self.leases += 1
            except (BlockingIOError, InterruptedError):
                pass                # emulator not reading (stopped): it has leases queued
            except OSError:
                self._close_locked()
                return
            self._drain()

    def close(self) -> None:
        """Stop leasing: the emulator runs on in real time (as after a crash of this host)."""
        with self._lock:
            self._close_locked()

    @property
    def attached(self) -> bool:
        return self._closed_at is None

    def describe(self) -> str:
        return f"emulator time (ctr_sim pid {self.pid}, lease {self.lease_s * 1e3:.0f} ms)"


# ---------------------------------------------------------------------------
# driver
# ---------------------------------------------------------------------------

class _Pending:
    __slots__ = ("cmd", "event", "reply", "error", "sent", "callback")

    def __init__(self, cmd: str, callback: Callable[[Frame], None] | None = None):
        self.cmd = cmd
        self.event = threading.Event()
        self.reply: Frame | None = None
        self.error: BaseException | None = None
        self.sent = time.monotonic()
        self.callback = callback


class ArduinoActuator(Actuator):
    """:class:`~rig.hw.actuator.Actuator` on the Arduino Uno firmware.

    Parameters
    ----------
    url:
        anything :func:`serial.serial_for_url` accepts: ``/dev/ttyACM0``,
        ``/dev/pts/7`` (emulator), ``socket://host:port``, ...
    limits:
        soft limits; checked on the host before sending and also pushed to the
        firmware (``LIM``) at every handshake, so that raw commands are
        refused by the controller too.
    command_timeout_s, retries:
        each command waits ``command_timeout_s`` for its reply and is re-sent
        up to ``retries`` times on timeout or on a damaged-frame error.
    ready_timeout_s:
        how long the handshake waits for the controller (an Uno reboots when
        its port is opened: bootloader ~0.5-1.6 s).
    heartbeat_s:
        heartbeat period (wall-clock time); must stay well under the
        firmware's 100 ms link watchdog.
    tolerance:
        position tolerance of :meth:`wait_settled` (mm, deg).
    clock:
        time base of the timeouts above and of :meth:`home` /
        :meth:`wait_settled`: ``"auto"`` (default) uses the emulator's
        simulated time when ``url`` is a pty served by ``rig/hw/sim/ctr_sim``
        and real time otherwise; ``"real"`` always real time (the emulator
        then runs free in real time, as a real Uno would); ``"emulator"``
        requires the emulator's clock channel.  See :class:`EmulatorClock`.
    """

    def __init__(self, url: str, limits: SoftLimits | None = None, *,
                 baudrate: int = 115200,
                 command_timeout_s: float = 0.25,
                 retries: int = 2,
                 ready_timeout_s: float = 3.0,
                 heartbeat_s: float = 0.02,
                 tolerance: JointValues = JointValues(0.05, 0.5),
                 clock: str = "auto",
                 connect: bool = True):
        super().__init__(limits)
        if clock not in ("auto", "real", "emulator"):
            raise ValueError(f"clock must be 'auto', 'real' or 'emulator', got {clock!r}")
        self.clock_mode = clock
        self.clock: LinkClock = LinkClock()
        self.url = url
        self.port = url
        self.baudrate = baudrate
        self.command_timeout_s = command_timeout_s
        self.retries = retries
        self.ready_timeout_s = ready_timeout_s
        self.heartbeat_s = heartbeat_s
        self.tolerance = tolerance

        self.firmware_version: str | None = None
        self.resets = 0                  # MCU resets seen after the first handshake
        self.watchdog_events = 0         # "$0,WDOG" frames received
        self.bad_frames = 0              # undecodable lines received
        self.async_errors: list[Frame] = []   # ERR frames with seq 0 (noise on the line)
        self.max_heartbeat_gap_s = 0.0   # longest interval between two heartbeats sent (link time)
        self.bytes_written = 0           # bytes written to the port since it was opened

        self._ser: serial.SerialBase | None = None
        self._wlock = threading.Lock()
        self._plock = threading.Lock()
        self._pending: dict[int, _Pending] = {}
        self._seq = itertools.count(1)
        self._closing = threading.Event()
        self._ready = threading.Event()          # handshake complete
        self._booted = threading.Event()         # READY or VER seen during handshake
        self._handshaken = False
        self._reset_note: str | None = None      # unreported reset
        self._reset_epoch = 0
        self._link_error: LinkError | None = None
        self._hb_paused = threading.Event()
        self._last_status: Status | None = None
        self._reader: threading.Thread | None = None
        self._heartbeat: threading.Thread | None = None
        if connect:
            self.open()

    # -- connection --------------------------------------------------------
    def open(self) -> None:
        """Open the port, start the reader and do the ready handshake."""
        if self._ser is not None:
            return
        try:
            self._ser = serial.serial_for_url(self.url, baudrate=self.baudrate,
                                              timeout=0.02, write_timeout=1.0)
        except (serial.SerialException, OSError, ValueError) as e:
            raise LinkError(f"{self.port}: open failed: {e}") from None
        try:
            self._ser.reset_input_buffer()
        except (serial.SerialException, OSError, AttributeError):
            pass
        self.bytes_written = 0
        clock = None
        if self.clock_mode != "real":
            clock = EmulatorClock.attach(self.url, self.ready_timeout_s)
            if clock is None and self.clock_mode == "emulator":
                self._ser.close()
                self._ser = None
                raise LinkError(f"{self.port}: clock='emulator' but no ctr_sim clock channel serves this port "
                                f"(not an emulator pty, or ctr_sim --no-sync)")
        self.clock = clock or LinkClock()
        self._closing.clear()
        self._link_error = None
        self._handshaken = False
        self._reset_note = None
        self._reader = threading.Thread(target=self._read_loop, name=f"arduino-rx {self.port}",
                                        daemon=True)
        self._reader.start()
        # the heartbeat thread runs from the start: before the handshake it only
        # leases the emulator its time (no HB is sent until the controller is ready)
        self._heartbeat = threading.Thread(target=self._heartbeat_loop,
                                           name=f"arduino-hb {self.port}", daemon=True)
        self._heartbeat.start()
        try:
            self._handshake(self.ready_timeout_s)
        except BaseException:
            self.close()
            raise

    def close(self) -> None:
        """Stop the threads and close the port.  No STOP is sent: the firmware's
        link watchdog stops the motors 100 ms after the last heartbeat.  Call
        :meth:`stop` first (the context manager does) for an immediate stop."""
        self._closing.set()
        self._ready.clear()
        for t in (self._heartbeat, self._reader):
            if t is not None and t is not threading.current_thread():
                t.join(timeout=1.0)
        self._heartbeat = self._reader = None
        self.clock.close()
        if self._ser is not None:
            try:
                self._ser.close()
            except Exception:       # pragma: no cover - best effort
                pass
            self._ser = None
        self._fail_pending(LinkError(f"{self.port}: closed"))

    @property
    def connected(self) -> bool:
        return self._ser is not None and self._link_error is None and not self._closing.is_set()

    def _handshake(self, timeout_s: float) -> None:
        """Wait for the controller (READY after its reboot, or a reply to a VER
        probe when the port did not reset it), then push the soft limits."""
        self._ready.clear()
        self._booted.clear()
        clock = self.clock
        deadline = clock.now() + timeout_s
        next_probe = clock.now() + 0.25
        while not self._booted.is_set():
            self._raise_link_error("handshake")
            now = clock.now()
            if now >= deadline:
                raise LinkError(f"{self.port}: handshake: no READY and no reply to VER "
                                f"within {timeout_s:.1f}s (firmware flashed? right port/baud?)")
            if now >= next_probe:
                self._send("VER", callback=lambda f: self._booted.set() if f.kind == "OK" else None)
                next_probe = now + 0.5
            self._booted.wait(min(0.02, max(0.0, deadline - now)))
        ver = self._command("VER", handshake=True)
        if len(ver.args) < 2 or ver.int_arg(1) != PROTO_VERSION:
            raise LinkError(f"{self.port}: handshake: controller speaks protocol "
                            f"{ver.args[1] if len(ver.args) > 1 else '?'}, driver speaks {PROTO_VERSION}")
        self.firmware_version = ver.args[0]
        for j, lo, hi in Protocol.limits_to_wire(self.limits):
            try:
                self._command("LIM", j, lo, hi, handshake=True)
            except FirmwareError as e:
                raise ValueError(f"{self.port}: soft limits {JOINTS[j]} [{lo / 1000:g}, {hi / 1000:g}] "
                                 f"exceed the controller's travel ({e.name})") from None
        self._last_status = Protocol.parse_stat(self._command("STAT", handshake=True), time.monotonic())
        self._handshaken = True
        self._ready.set()
        log.info("%s: connected, firmware %s, timeouts in %s", self.port, self.firmware_version,
                 self.clock.describe())

    def _rehandshake(self, epoch: int) -> None:
        try:
            self._handshake_after_reset()
        except Exception as e:          # reported by the next command
            log.error("%s: re-handshake after reset failed: %s", self.port, e)
            if self._reset_epoch == epoch and self._link_error is None:
                self._link_error = LinkError(f"{self.port}: re-handshake after controller reset failed: {e}")
                self._ready.set()

    def _handshake_after_reset(self) -> None:
        self._booted.set()              # READY already received
        ver = self._command("VER", handshake=True)
        self.firmware_version = ver.args[0] if ver.args else None
        for j, lo, hi in Protocol.limits_to_wire(self.limits):
            self._command("LIM", j, lo, hi, handshake=True)
        self._ready.set()
        log.warning("%s: re-handshake after controller reset done", self.port)

    # -- background threads -----------------------------------------------
    def _read_loop(self) -> None:
        splitter = LineSplitter()
        ser = self._ser
        while not self._closing.is_set():
            try:
                data = ser.read(max(1, ser.in_waiting or 0))
            except (serial.SerialException, OSError, TypeError, AttributeError) as e:
                if not self._closing.is_set():
                    self._link_error = LinkError(f"{self.port}: link lost: {e}")
                    self._fail_pending(self._link_error)
                    self._ready.set()     # wake waiters; they re-check the link
                return
            if not data:
                continue
            now = time.monotonic()
            for line in splitter.feed(data):
                try:
                    frame = Protocol.decode(line)
                except ProtocolError as e:
                    self.bad_frames += 1
                    log.debug("%s: dropped line: %s", self.port, e)
                    continue
                self._dispatch(frame, now)

    def _dispatch(self, frame: Frame, now: float) -> None:
        if frame.seq == 0:
            if frame.kind == "READY":
                self._on_ready(frame, now)
            elif frame.kind == "WDOG":
                self.watchdog_events += 1
                log.warning("%s: controller link watchdog stopped the motors (%s ms without a frame)",
                            self.port, frame.args[0] if frame.args else "?")
            elif frame.kind == "ERR":
                self.async_errors.append(frame)
                del self.async_errors[:-100]
            elif frame.kind == "STAT":
                try:
                    self._last_status = Protocol.parse_stat(frame, now)
                except ProtocolError:
                    self.bad_frames += 1
            return
        with self._plock:
            p = self._pending.pop(frame.seq, None)
        if p is None:
            log.debug("%s: reply without request: %s", self.port, frame)
            return
        if frame.kind == "STAT":
            try:
                self._last_status = Protocol.parse_stat(frame, now)
            except ProtocolError:
                self.bad_frames += 1
        p.reply = frame
        p.event.set()
        if p.callback is not None:
            try:
                p.callback(frame)
            except Exception:           # pragma: no cover
                log.exception("%s: reply callback failed", self.port)

    def _on_ready(self, frame: Frame, now: float) -> None:
        if not self._handshaken:
            self._booted.set()
            return
        # the controller rebooted under our feet
        self.resets += 1
        self._reset_epoch += 1
        cause = frame.args[1] if len(frame.args) > 1 else "?"
        self._reset_note = (f"{self.port}: controller reset detected (READY fw {frame.args[0] if frame.args else '?'}"
                            f", MCUSR 0x{cause}); motors are stopped, link re-established, "
                            f"joints must be homed again")
        log.error("%s", self._reset_note)
        self._ready.clear()
        self._last_target = None
        self._fail_pending(ActuatorResetError(self._reset_note))
        threading.Thread(target=self._rehandshake, args=(self._reset_epoch,),
                         name=f"arduino-rehandshake {self.port}", daemon=True).start()

    def _heartbeat_loop(self) -> None:
        """Every ``heartbeat_s`` of wall-clock time: an ``HB`` (when connected and
        not paused), then a tick of the link clock (the emulator's lease)."""
        period = self.heartbeat_s
        clock = self.clock
        next_t = time.monotonic()
        last = None
        try:
            while not self._closing.wait(max(0.0, next_t - time.monotonic())):
                wall = time.monotonic()
                next_t += period
                if next_t < wall:
                    next_t = wall + period
                if self._hb_paused.is_set() or not self._ready.is_set() or self._link_error:
                    last = None
                else:
                    now = clock.now()
                    if last is not None and now - last > self.max_heartbeat_gap_s:
                        self.max_heartbeat_gap_s = now - last
                        if now - last > 0.07:
                            log.warning("%s: heartbeat delayed %.0f ms (the controller stops the motors "
                                        "after 100 ms without a frame)", self.port, (now - last) * 1e3)
                    last = now
                    self._send("HB")
                    self._expire_pending()
                clock.tick(self.bytes_written)
        except LinkError:
            pass
        finally:
            # a host that no longer sends heartbeats must not hold the emulator's time
            if not self._closing.is_set():
                clock.close()

    # -- request / reply -----------------------------------------------------
    def _next_seq(self) -> int:
        s = next(self._seq) % 65536
        if s == 0:
            s = next(self._seq) % 65536
        return s

    def _send(self, cmd: str, *args: int | str, callback=None) -> _Pending:
        ser = self._ser
        if ser is None:
            raise LinkError(f"{self.port}: {cmd}: port is closed")
        p = _Pending(cmd, callback)
        with self._wlock:
            seq = self._next_seq()
            data = Protocol.encode(seq, cmd, *args)
            with self._plock:
                self._pending[seq] = p
            try:
                ser.write(data)
            except (serial.SerialException, OSError) as e:
                with self._plock:
                    self._pending.pop(seq, None)
                self._link_error = LinkError(f"{self.port}: {cmd}: write failed: {e}")
                raise self._link_error from None
            self.bytes_written += len(data)
        return p

    def _expire_pending(self, max_age_s: float = 2.0) -> None:
        now = time.monotonic()
        with self._plock:
            old = [s for s, p in self._pending.items() if now - p.sent > max_age_s]
            for s in old:
                self._pending.pop(s)

    def _fail_pending(self, err: BaseException) -> None:
        with self._plock:
            items = list(self._pending.values())
            self._pending.clear()
        for p in items:
            p.error = err
            p.event.set()

    def _raise_link_error(self, cmd: str) -> None:
        if self._link_error is not None:
            raise LinkError(f"{self._link_error} (during {cmd})")
        if self._ser is None:
            raise LinkError(f"{self.port}: {cmd}: port is closed")

    def _check_reset(self) -> None:
        note = self._reset_note
        if note is not None:
            self._reset_note = None
            raise ActuatorResetError(note)

    def _command(self, cmd: str, *args: int | str, timeout_s: float | None = None,
                 retries: int | None = None, handshake: bool = False) -> Frame:
        timeout_s = self.command_timeout_s if timeout_s is None else timeout_s
        retries = self.retries if retries is None else retries
        if not handshake:
            self._raise_link_error(cmd)
            self._check_reset()
            if not self.clock.wait(self._ready, self.ready_timeout_s):
                self._raise_link_error(cmd)
                raise LinkError(f"{self.port}: {cmd}: controller not ready "
                                f"(handshake pending for {self.ready_timeout_s:.1f}s)")
            self._check_reset()
        epoch = self._reset_epoch
        last = "no reply"
        for attempt in range(retries + 1):
            self._raise_link_error(cmd)
            p = self._send(cmd, *args)
            if not self.clock.wait(p.event, timeout_s):
                with self._plock:
                    self._pending.pop(next((s for s, q in self._pending.items() if q is p), -1), None)
                last = f"no reply within {timeout_s * 1000:.0f} ms"
                continue
            if p.error is not None:
                if isinstance(p.error, ActuatorResetError) and not handshake:
                    self._reset_note = None
                raise type(p.error)(f"{p.error} (during {cmd})") from None
            f = p.reply
            if f.kind == "ERR":
                code, name = Protocol.error_of(f)
                if code in RETRYABLE_ERRORS:
                    last = f"ERR {code} {name}"
                    continue
                raise FirmwareError(f"{self.port}: {cmd}{''.join(',' + str(a) for a in args)} refused: "
                                    f"ERR {code} {name}", code, name)
            if not handshake and epoch != self._reset_epoch:
                self._check_reset()
            return f
        raise TimeoutError(f"{self.port}: {cmd}: {last} after {retries + 1} attempt(s)")

    # -- public API ----------------------------------------------------------
    def command(self, cmd: str, *args: int | str, timeout_s: float | None = None,
                retries: int | None = None) -> Frame:
        """Send a raw command and return its reply frame (diagnostics and
        tests).  No host-side checks: the firmware's checks still apply."""
        return self._command(cmd, *args, timeout_s=timeout_s, retries=retries)

    def status(self) -> Status:
        """Fresh ``STAT`` from the controller."""
        return Protocol.parse_stat(self._command("STAT"), time.monotonic())

    @property
    def last_status(self) -> Status | None:
        """Latest status seen (heartbeat replies refresh it every ``heartbeat_s``)."""
        return self._last_status

    def position(self) -> JointValues:
        return self.status().position

    def home(self, timeout_s: float = 30.0) -> None:
        """Home both joints: the insertion stage seeks its home switch (the
        switch edge becomes 0 mm); the rotation has no index, its current
        angle becomes 0 deg.  Blocks until homed and settled at (0, 0)."""
        self._command("HOME")
        self._last_target = None
        clock = self.clock
        deadline = clock.now() + timeout_s
        while True:
            st = self.status()
            if st.home_failed:
                raise ActuatorError(f"{self.port}: HOME: insertion_mm home switch not found "
                                    f"(controller timeout)")
            if st.watchdog_tripped:
                raise ActuatorError(f"{self.port}: HOME: aborted by the controller's link watchdog")
            if st.homed and not st.homing:
                # the stage overshoots the switch while braking: wait until
                # the PID has brought both joints back to their zeros
                self._last_target = JointValues(0.0, 0.0)
                self.wait_settled(max(0.5, deadline - clock.now()))
                return
            if not st.homing:
                raise ActuatorError(f"{self.port}: HOME: homing stopped before completion")
            if clock.now() > deadline:
                raise TimeoutError(f"{self.port}: HOME: joint insertion_mm did not reach its home "
                                   f"switch within {timeout_s:.1f}s (at {st.position.insertion_mm:.3f} mm)")
            time.sleep(0.02)

    def _send_move(self, target: JointValues) -> None:
        self._command("MOV", *Protocol.to_wire(target))

    def wait_settled(self, timeout_s: float = 10.0) -> JointValues:
        target = self._last_target
        if target is None:
            self._check_reset()
            raise ActuatorError(f"{self.port}: wait_settled: no target (call move_to or home first)")
        clock = self.clock
        deadline = clock.now() + timeout_s
        while True:
            st = self.status()
            if st.watchdog_tripped or not st.enabled:
                # A controller that reset while this STAT was on the wire answers from its new
                # boot (motors off, no heartbeat yet): the reset, seen by the reader before the
                # reply, is the cause to report.
                self._check_reset()
            if st.watchdog_tripped:
                raise ActuatorError(f"{self.port}: wait_settled: motors stopped by the controller's "
                                    f"link watchdog (no heartbeat for 100 ms)")
            if not st.enabled:
                raise ActuatorError(f"{self.port}: wait_settled: motors are not under control (stopped)")
            bad = []
            for j, name in enumerate(JOINTS):
                err = abs(getattr(st.position, name) - getattr(target, name))
                if not st.settled[j] or err > getattr(self.tolerance, name):
                    bad.append(f"{name} at {getattr(st.position, name):.3f} (target {getattr(target, name):.3f})")
            if not bad:
                return st.position
            if clock.now() > deadline:
                raise TimeoutError(f"{self.port}: wait_settled: joint {', '.join(bad)} "
                                   f"not settled within {timeout_s:.1f}s")
            time.sleep(0.01)

    def stop(self) -> None:
        self._last_target = None
        self._command("STOP")

    # -- fault injection (tests, bench checks) ----------------------------------
    def pause_heartbeat(self) -> None:
        """Stop sending heartbeats (the controller stops the motors after 100 ms)."""
        self._hb_paused.set()

    def resume_heartbeat(self) -> None:
        self._hb_paused.clear()

    def write_raw(self, data: bytes) -> None:
        """Write bytes as they are, bypassing the protocol layer."""
        ser = self._ser
        if ser is None:
            raise LinkError(f"{self.port}: write_raw: port is closed")
        with self._wlock:
            ser.write(data)
            self.bytes_written += len(data)

    def __repr__(self) -> str:
        return f"ArduinoActuator({self.port!r}, firmware={self.firmware_version!r})"
