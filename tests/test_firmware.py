"""Actuator firmware + driver tests.

1. Pure protocol tests (rig.hw.arduino.Protocol & co., rig.hw.actuator) -- no
   hardware, always run.
2. Firmware-in-the-loop tests: the real firmware (rig/hw/firmware) runs on an
   emulated ATmega328P (rig/hw/sim/ctr_sim, libsimavr) with simulated motors,
   encoders and home switch; ArduinoActuator talks to it over a pty.  The
   harness prints the simulated time, plant encoder counts and PWM outputs,
   which is what the latency measurements below use.  Skipped only when
   avr-gcc is missing.

   The driver attaches to the emulator's clock channel (rig.hw.arduino.EmulatorClock):
   its heartbeats lease the emulator simulated time and its timeouts count
   simulated time, so these tests hold on a loaded machine; the real-time
   semantics of a real Uno (clock="real", no lease) are checked too.
"""

from __future__ import annotations

import os
import random
import signal
import statistics
import sys
import time
from unittest import mock

import pytest

from rig.hw.actuator import (
    ActuatorError,
    ActuatorResetError,
    FirmwareError,
    JointValues,
    SoftLimits,
)
from rig.hw.arduino import (
    ArduinoActuator,
    EmulatorClock,
    Frame,
    LinkClock,
    LineSplitter,
    Protocol,
    ProtocolError,
    F_HOMED,
    F_WDOG,
)

from figures import record

try:                                    # tests/ as a package or as a rootdir
    from .fil_fixtures import *  # noqa: F401,F403
except ImportError:
    from fil_fixtures import *  # noqa: F401,F403

COUNTS_PER_MM = 400
COUNTS_PER_DEG = 20
LINK_TIMEOUT_MS = 100.0
#: "nothing moved": a holding servo creeps by a few counts (2.5 um each);
#: any refused MOV in these tests would have moved >= 5 mm = 2000 counts
HOLD_COUNTS = 16


def _report(key, value):
    """A measured figure, printed in the terminal summary (tests/figures.py)."""
    record("firmware-in-the-loop", key, value)


# ===========================================================================
# 1. protocol, pure
# ===========================================================================

class TestProtocol:
    def test_checksum_matches_firmware_frames(self):
        # frames captured from the firmware
        for raw in (b"$1,OK,1.0.0,1,400,20*2F\n", b"$0,READY,1.0.0,0*56\n", b"$2,STAT,0,0,0*10\n"):
            f = Protocol.decode(raw)
            assert Protocol.encode(f.seq, f.kind, *f.args) == raw

    def test_roundtrip(self):
        raw = Protocol.encode(4711, "MOV", 20000, -90000)
        assert raw.startswith(b"$4711,MOV,20000,-90000*") and raw.endswith(b"\n")
        f = Protocol.decode(raw)
        assert f == Frame(4711, "MOV", ("20000", "-90000"))
        assert f.int_arg(1) == -90000

    @pytest.mark.parametrize("line, msg", [
        (b"4711,MOV*00", "start"),
        (b"$1,HB", "checksum"),
        (b"$1,HB*4", "checksum"),
        (b"$1,HB*ZZ", "checksum digits"),
        (b"$1,HB*00", "mismatch"),
        (b"$x,HB*" + b"%02X" % Protocol.checksum(b"x,HB"), "malformed"),
        (b"$99999,HB*" + b"%02X" % Protocol.checksum(b"99999,HB"), "range"),
        (b"$1,\xff*" + b"%02X" % Protocol.checksum(b"1,\xff"), "ASCII"),
    ])
    def test_decode_rejects(self, line, msg):
        with pytest.raises(ProtocolError, match=msg):
            Protocol.decode(line)

    @pytest.mark.parametrize("args", [("HB", "a,b"), ("mov",), ("TOOLONGCMD",), ("HB", 1.5), ("HB", True)])
    def test_encode_rejects(self, args):
        with pytest.raises(ValueError):
            Protocol.encode(1, *args)

    def test_encode_rejects_overlong_and_bad_seq(self):
        with pytest.raises(ValueError, match="longer"):
            Protocol.encode(1, "MOV", *([123456789] * 7))
        with pytest.raises(ValueError, match="sequence"):
            Protocol.encode(70000, "HB")

    def test_splitter_fragments_and_noise(self):
        s = LineSplitter()
        a = Protocol.encode(1, "HB")
        b = Protocol.encode(2, "STAT")
        out = []
        data = b"\x00garbage\n" + a + b"zz" + b
        for i in range(len(data)):           # byte by byte
            out += s.feed(data[i:i + 1])
        assert out == [a.rstrip(b"\n"), b.rstrip(b"\n")]
        assert s.dropped == 2                # noise line + noise before '$'

    def test_splitter_drops_overlong(self):
        s = LineSplitter(max_len=16)
        assert s.feed(b"$" + b"x" * 100) == []
        assert s.feed(Protocol.encode(3, "HB")) == [Protocol.encode(3, "HB").rstrip(b"\n")]

    def test_units_and_status(self):
        assert Protocol.to_wire(JointValues(12.3456, -90.0004)) == (12346, -90000)
        assert Protocol.from_wire(2500, 50) == JointValues(2.5, 0.05)
        st = Protocol.parse_stat(Frame(0, "STAT", ("20000", "-45000", "1D")))
        assert st.position == JointValues(20.0, -45.0)
        assert st.homed and st.enabled and st.settled == (True, True) and not st.watchdog_tripped
        assert Protocol.parse_stat(Frame(0, "STAT", ("0", "0", hex(F_WDOG | F_HOMED)[2:]))).watchdog_tripped
        with pytest.raises(ProtocolError):
            Protocol.parse_stat(Frame(0, "STAT", ("1", "x", "0")))
        assert Protocol.error_of(Frame(3, "ERR", ("4", "LIMIT"))) == (4, "LIMIT")

    def test_limits_to_wire_round_inwards(self):
        lim = SoftLimits(insertion_mm=(0.0004, 50.0009), rotation_deg=(-180.0, 180.0))
        assert Protocol.limits_to_wire(lim) == [(0, 1, 50000), (1, -180000, 180000)]


class TestSoftLimits:
    def test_from_dict_forms(self):
        lim = SoftLimits.from_dict({"insertion_mm": {"min": 0, "max": 80},
                                    "rotation_deg": [-90, 90.5]})
        assert lim.insertion_mm == (0.0, 80.0) and lim.rotation_deg == (-90.0, 90.5)
        assert SoftLimits.from_dict({}) == SoftLimits()
        assert SoftLimits.from_dict(lim.to_dict()) == lim

    @pytest.mark.parametrize("d, key", [
        ({"insertion": [0, 1]}, "limits.insertion"),
        ({"insertion_mm": {"min": 0}}, "limits.insertion_mm.max"),
        ({"insertion_mm": {"min": 0, "max": "x"}}, "limits.insertion_mm.max"),
        ({"insertion_mm": {"min": 0, "max": 1, "mx": 2}}, "limits.insertion_mm.mx"),
        ({"rotation_deg": [5, 1]}, "limits.rotation_deg"),
        ({"rotation_deg": [1, 2, 3]}, "limits.rotation_deg"),
        ({"rotation_deg": [float("nan"), 2]}, "limits.rotation_deg.min"),
        ({"rotation_deg": 3}, "limits.rotation_deg"),
    ])
    def test_from_dict_errors_name_the_key(self, d, key):
        with pytest.raises(ValueError, match=key.replace(".", r"\.")):
            SoftLimits.from_dict(d, prefix="limits.")

    def test_check(self):
        lim = SoftLimits(insertion_mm=(0, 50), rotation_deg=(-90, 90))
        lim.check(JointValues(50, -90))
        with pytest.raises(ValueError, match="rotation_deg=91"):
            lim.check(JointValues(10, 91))

    def test_coerce(self):
        base = JointValues(1, 2)
        assert JointValues.coerce({"rotation_deg": 5}, base) == JointValues(1, 5)
        with pytest.raises(ValueError, match="insertion_mm"):
            JointValues.coerce({"insertion_mm": float("inf"), "rotation_deg": 0})
        with pytest.raises(ValueError, match="unknown joint 'x'"):
            JointValues.coerce({"x": 1}, base)
        with pytest.raises(ValueError, match="missing joint"):
            JointValues.coerce({"rotation_deg": 1})


# the firmware's own parser (rig/hw/firmware/protocol.c, pure C) built for the
# host and driven through ctypes: differential test against Protocol
_GLUE = r'''
#include <stdio.h>
#include <string.h>
#include "protocol.h"
int feed(const unsigned char *d, int n, char *out, int cap) {
    line_rx_t lr; frame_t f; int k = 0; proto_rx_init(&lr);
    for (int i = 0; i < n; i++) {
        int r = proto_feed(&lr, d[i], &f);
        if (r == 1) {
            k += snprintf(out + k, cap - k, "F %u %s", f.seq, f.cmd);
            for (int a = 0; a < f.nargs; a++) k += snprintf(out + k, cap - k, " %ld", (long)f.args[a]);
            k += snprintf(out + k, cap - k, "\n");
        } else if (r < 0) {
            k += snprintf(out + k, cap - k, "E %d %u\n", -r, f.seq);
        }
    }
    return k;
}
int build(unsigned seq, const char *kind, int n, const long *v, char *out) {
    tx_frame_t t; tx_begin(&t, (unsigned short)seq, kind);
    for (int i = 0; i < n; i++) tx_int(&t, (int)v[i]);
    strcpy(out, tx_finish(&t)); return (int)strlen(out);
}
'''


@pytest.fixture(scope="module")
def cproto(tmp_path_factory):
    import ctypes
    import shutil
    import subprocess
    from pathlib import Path
    cc = shutil.which("gcc") or shutil.which("cc")
    if cc is None:
        pytest.skip("no host C compiler")
    fw = Path(__file__).resolve().parents[1] / "rig" / "hw" / "firmware"
    d = tmp_path_factory.mktemp("cproto")
    (d / "glue.c").write_text(_GLUE)
    so = d / "libproto.so"
    subprocess.run([cc, "-std=gnu99", "-Wall", "-Werror", "-shared", "-fPIC", f"-I{fw}",
                    "-o", str(so), str(fw / "protocol.c"), str(d / "glue.c")], check=True)
    lib = ctypes.CDLL(str(so))

    def feed(data: bytes) -> list[str]:
        out = ctypes.create_string_buffer(1 << 16)
        n = lib.feed(data, len(data), out, len(out))
        return out.raw[:n].decode().splitlines()

    def build(seq, kind, *vals) -> bytes:
        out = ctypes.create_string_buffer(128)
        arr = (ctypes.c_long * max(1, len(vals)))(*vals)
        n = lib.build(seq, kind.encode(), len(vals), arr, out)
        return out.raw[:n]
    return feed, build


class TestFirmwareParser:
    def test_accepts_what_the_host_encodes(self, cproto):
        feed, _ = cproto
        rnd = random.Random(7)
        frames, expect = b"", []
        for _ in range(300):
            seq = rnd.randrange(65536)
            cmd = rnd.choice(["MOV", "HB", "LIM", "STAT", "X9"])
            args = [rnd.randrange(-999_999_999, 1_000_000_000) for _ in range(rnd.randrange(5))]
            frames += Protocol.encode(seq, cmd, *args)
            expect.append(" ".join(["F", str(seq), cmd] + [str(a) for a in args]))
        assert feed(b"noise\x00\xff" + frames) == expect

    def test_rejects_damage(self, cproto):
        feed, _ = cproto
        good = Protocol.encode(12, "MOV", 20000, 0)
        assert feed(good[:-3] + b"00\n") == ["E 1 12"]                    # BADCS
        assert feed(good.replace(b"20000", b"20001")) == ["E 1 12"]
        assert feed(good[:8] + good) == ["E 7 12", "F 12 MOV 20000 0"]     # TRUNC
        assert feed(b"$12,MOV,\x01" + good) == ["E 2 12", "F 12 MOV 20000 0"]
        assert feed(b"$" + b"1" * 70 + b"\n") == ["E 7 0"]
        assert feed(b"$1,HB\n") == ["E 2 1"]                               # no checksum
        for bad in (b"1,mov", b"1,MOV,1x", b"1,MOV,1234567890", b"1,TOOLONGX", b"70000,HB",
                    b"1,", b"1,MOV,1,2,3,4,5", b"-1,HB"):
            body = b"$" + bad + b"*%02X\n" % Protocol.checksum(bad)
            out = feed(body)
            assert len(out) == 1 and out[0].startswith("E "), (bad, out)
            assert out[0].split()[1] in ("2", "8"), (bad, out)

    def test_builder_matches_host(self, cproto):
        _, build = cproto
        rnd = random.Random(3)
        for _ in range(200):
            seq = rnd.randrange(65536)
            vals = [rnd.randrange(-2**31, 2**31) for _ in range(rnd.randrange(4))]
            assert build(seq, "STAT", *vals) == Protocol.encode(seq, "STAT", *vals)


class TestDriverWithoutController:
    def test_open_failure_names_port(self, tmp_path):
        url = str(tmp_path / "no-such-tty")
        with pytest.raises(ConnectionError, match=f"^{url}: open failed"):
            ArduinoActuator(url)

    def test_handshake_timeout_on_silent_port(self):
        master, slave = os.openpty()
        try:
            url = os.ttyname(slave)
            t = time.monotonic()
            with pytest.raises(ConnectionError, match=f"^{url}: handshake: no READY and no reply to VER"):
                ArduinoActuator(url, ready_timeout_s=0.6)
            assert time.monotonic() - t < 2.0
            # the VER probes went out, framed and checksummed
            os.set_blocking(master, False)
            sent = os.read(master, 4096)
            assert Protocol.decode(sent.splitlines()[0]).kind == "VER"
        finally:
            os.close(master)
            os.close(slave)

    def test_real_ports_keep_real_time(self):
        """A pty (or serial port) that no ctr_sim serves gets no emulator clock: real time."""
        master, slave = os.openpty()
        try:
            url = os.ttyname(slave)
            assert EmulatorClock.attach(url) is None
            assert EmulatorClock.attach("socket://localhost:9") is None
            assert EmulatorClock.attach("/dev/null") is None
            with pytest.raises(ConnectionError, match=f"^{url}: clock='emulator' but no ctr_sim clock channel"):
                ArduinoActuator(url, clock="emulator")
            with pytest.raises(ValueError, match="clock must be"):
                ArduinoActuator(url, clock="sim")
            clock = LinkClock()
            assert not clock.emulated and abs(clock.now() - time.monotonic()) < 0.01
        finally:
            os.close(master)
            os.close(slave)


# ===========================================================================
# 2. firmware in the loop
# ===========================================================================

LIMITS = SoftLimits(insertion_mm=(0.0, 60.0), rotation_deg=(-180.0, 180.0))


@pytest.fixture
def rig(sim_factory):
    """(harness, connected actuator) with the insertion stage 3 mm from home."""
    h = sim_factory("--x0-mm", "3", "--th0-deg", "10")
    act = ArduinoActuator(h.pty, LIMITS)
    yield h, act
    act.close()


@pytest.fixture
def homed_rig(rig):
    h, act = rig
    act.home(timeout_s=10)
    return h, act


def _moving_insertion(h, act, target_mm=55.0):
    """Start a long insertion move and wait until the motor is driven."""
    act.move_to({"insertion_mm": target_mm, "rotation_deg": 90.0})
    t = h.wait_tline(lambda t: abs(t.pwm0) > 50, timeout_s=2)
    time.sleep(0.15)
    return t


def _assert_stopped_after(h, ev, label):
    latency_ms = (ev.us - int(ev.fields[0])) / 1000.0
    # motors really come to rest: plant encoder barely moves afterwards
    time.sleep(0.15)
    after = h.tlines_between(ev.us, ev.us + 120_000)
    assert after, "no status lines after the stop"
    assert all(t.pwm0 == 0 and t.pwm1 == 0 for t in after), f"{label}: PWM re-applied"
    drift = max(abs(t.pos0 - after[0].pos0) for t in after)
    assert drift < 0.5 * COUNTS_PER_MM, f"{label}: insertion still moved {drift} counts after the stop"
    return latency_ms


def test_handshake(rig):
    h, act = rig
    assert act.connected and act.firmware_version == "1.0.0"
    assert act.clock.emulated, "the driver did not attach to the emulator's clock channel"
    # the pty open reset the MCU (like the Uno's DTR) and the driver consumed READY
    assert h.wait_event("R").fields == ("open",)
    assert act.resets == 0
    st = act.status()
    assert not st.homed and not st.enabled
    assert st.position == JointValues(0.0, 0.0)


def test_clock_channel(sim_factory):
    """ctr_sim's clock channel: found from the pty path (also through a --link
    symlink), reports simulated time, absent with --no-sync."""
    import tempfile
    link = os.path.join(tempfile.mkdtemp(), "ctr-uno")
    h = sim_factory("--link", link)
    assert h.wait_event("SYNC", after_us=-2, timeout_s=5).kind == "SYNC"     # "SYNC @ctr_sim:<pty>"
    clock = EmulatorClock.attach(link)
    assert clock is not None and clock.emulated and clock.pid == h.proc.pid
    assert clock.lease_s == pytest.approx(0.05)
    t0 = clock.now()
    for _ in range(10):                 # leases keep the simulation running
        clock.tick(0)
        time.sleep(0.02)
    assert clock.now() > t0
    clock.close()
    assert not clock.attached
    h2 = sim_factory("--no-sync")
    assert EmulatorClock.attach(h2.pty) is None


def test_handshake_without_reset_on_open(sim_factory):
    """socket:// or a port with DTR reset disabled: no READY, the VER probe answers."""
    h = sim_factory("--no-reset-on-open")
    time.sleep(0.1)                 # READY went out while nobody listened
    with ArduinoActuator(h.pty, LIMITS, ready_timeout_s=2.0) as act:
        assert act.firmware_version == "1.0.0"
        assert act.resets == 0


def test_home_move_and_settle(homed_rig):
    h, act = homed_rig
    st = act.status()
    assert st.homed and st.position.insertion_mm == pytest.approx(0.0, abs=0.03)
    # firmware zero == the switch edge == plant zero
    assert abs(h.latest().pos0) <= 12
    t0 = time.monotonic()
    target = act.move_to({"insertion_mm": 12.5, "rotation_deg": -45.0})
    pos = act.wait_settled(timeout_s=5)
    dt = time.monotonic() - t0
    assert pos.insertion_mm == pytest.approx(12.5, abs=0.02)
    assert pos.rotation_deg == pytest.approx(-45.0, abs=0.3)
    # ground truth from the simulated plant
    time.sleep(0.05)
    t = h.latest()
    assert t.pos0 == pytest.approx(12.5 * COUNTS_PER_MM, abs=16)
    rot0 = 10.0 * COUNTS_PER_DEG                           # rotation zero = angle at HOME
    assert t.pos1 - rot0 == pytest.approx(-45.0 * COUNTS_PER_DEG, abs=8)
    assert target == JointValues(12.5, -45.0)
    _report("move 12.5 mm / -45 deg settle time", f"{dt:.2f} s")
    # partial target keeps the other joint
    act.move_to({"rotation_deg": 30.0}, wait=True, timeout_s=5)
    assert act.position().insertion_mm == pytest.approx(12.5, abs=0.02)
    dbg = act.command("DBG")
    assert dbg.args[0] == "0", "encoder: illegal transitions"
    assert dbg.args[1] == "0", "UART RX overruns"
    assert dbg.args[2] == "0", "control loop ticks ran late"
    assert not [e for e in h.events if e.kind == "R" and e.fields != ("open",)], \
        "unexpected MCU reset (hardware watchdog?)"


def test_wait_settled_timeout_names_joint(homed_rig):
    h, act = homed_rig
    act.move_to({"insertion_mm": 55.0, "rotation_deg": 0.0})
    with pytest.raises(TimeoutError, match=r"insertion_mm at .*target 55\.000"):
        act.wait_settled(timeout_s=0.3)
    act.stop()


def test_round_trip_time(rig):
    h, act = rig
    rtts = []
    for _ in range(150):
        t = time.perf_counter()
        act.command("STAT")
        rtts.append((time.perf_counter() - t) * 1000)
    rtts.sort()
    med = statistics.median(rtts)
    p95 = rtts[int(0.95 * len(rtts)) - 1]
    _report("STAT round trip over the pty (ms)", f"median {med:.2f}, p95 {p95:.2f}, max {rtts[-1]:.2f}")
    # request 13 B + reply ~20 B at 115200 baud is ~3 ms on the wire alone
    assert med < 25 and p95 < 60


def test_soft_limits_host_side(homed_rig):
    h, act = homed_rig
    with mock.patch.object(act, "_send_move") as send:
        with pytest.raises(ValueError, match=r"insertion_mm=61 is outside the soft limits \[0, 60\]"):
            act.move_to({"insertion_mm": 61.0, "rotation_deg": 0.0})
        with pytest.raises(ValueError, match="rotation_deg"):
            act.move_to({"insertion_mm": 10.0, "rotation_deg": -181.0})
        send.assert_not_called()


def test_soft_limits_firmware_side(homed_rig):
    """Raw commands bypassing the host checks are refused by the firmware,
    both beyond the limits pushed with LIM and beyond its absolute travel."""
    h, act = homed_rig
    before = h.latest().pos0
    for args in ((61000, 0), (200000, 0), (10000, 181000), (-1, 0)):
        with pytest.raises(FirmwareError, match=r"MOV.*refused: ERR 4 LIMIT") as ei:
            act.command("MOV", *args)
        assert ei.value.code == 4
    # a fully raw frame written on the line
    n = len(act.async_errors)
    act.write_raw(Protocol.encode(0, "MOV", 65000, 0))
    deadline = time.monotonic() + 5
    while len(act.async_errors) == n and time.monotonic() < deadline:
        time.sleep(0.01)
    assert [Protocol.error_of(f)[0] for f in act.async_errors[n:]] == [4]
    # LIM cannot widen the firmware's absolute travel either
    with pytest.raises(FirmwareError, match="ERR 4 LIMIT"):
        act.command("LIM", 0, 0, 500000)
    time.sleep(0.1)
    assert abs(h.latest().pos0 - before) <= HOLD_COUNTS, "something moved"


def test_not_homed_refused(rig):
    h, act = rig
    with pytest.raises(FirmwareError, match="NOTHOMED"):
        act.move_to({"insertion_mm": 5.0, "rotation_deg": 0.0})


def _wait_async_errors(act, n, count, timeout_s=5.0):
    deadline = time.monotonic() + timeout_s
    while len(act.async_errors) < n + count and time.monotonic() < deadline:
        time.sleep(0.01)
    return [Protocol.error_of(f) for f in act.async_errors[n:]]


def test_fault_garbage_bytes(homed_rig):
    h, act = homed_rig
    act.move_to({"insertion_mm": 5.0, "rotation_deg": 0.0}, wait=True, timeout_s=5)
    before = h.latest()
    rnd = random.Random(1234)
    noise = bytes(rnd.randrange(256) for _ in range(3000))
    n = len(act.async_errors)
    for i in range(0, len(noise), 100):          # ~40 % of the line, between heartbeats
        act.write_raw(noise[i:i + 100])
        time.sleep(0.02)
    act.write_raw(b"$$$,,**\n\x00\xff$12a,MOV,1*\n")
    time.sleep(0.3)
    # still connected, still holding position, firmware healthy
    assert act.status().homed
    pos = act.wait_settled(timeout_s=2)
    assert pos.insertion_mm == pytest.approx(5.0, abs=0.02)
    after = h.latest()
    assert abs(after.pos0 - before.pos0) <= HOLD_COUNTS and abs(after.pos1 - before.pos1) <= 5
    errs = [e for e in act.async_errors[n:]]
    assert errs, "firmware did not report the damaged frames"
    dbg = act.command("DBG")
    assert dbg.args[1] == "0", "UART RX overrun"
    _report("garbage: 3000 random bytes", f"{len(errs)} ERR replies (seq 0), "
            f"{act.bad_frames} undecodable lines at the host, position held")


def test_fault_truncated_frames(homed_rig):
    h, act = homed_rig
    before = h.latest().pos0
    n = len(act.async_errors)
    # cut by the next frame, cut by noise, and over-long
    act.write_raw(b"$0,MOV,20000,0")
    act.write_raw(b"$0,MOV,20000,0*")
    act.write_raw(b"\x01")
    act.write_raw(b"$0,MOV," + b"1" * 80 + b"\n")
    act.write_raw(Protocol.encode(0, "STAT"))
    errs = _wait_async_errors(act, n, 3)
    codes = [c for c, _ in errs]
    assert codes[:3] == [7, 2, 7], errs               # TRUNC, SYNTAX, TRUNC
    time.sleep(0.2)
    assert abs(h.latest().pos0 - before) <= HOLD_COUNTS, "a truncated MOV moved the motor"
    assert act.status().position.insertion_mm == pytest.approx(0.0, abs=0.03)


def test_fault_bad_checksum(homed_rig):
    h, act = homed_rig
    before = h.latest().pos0
    n = len(act.async_errors)
    good = Protocol.encode(0, "MOV", 20000, 0)
    bad = good[:-3] + b"%02X\n" % (int(good[-3:-1], 16) ^ 0x5A)
    flipped = good.replace(b"20000", b"20100")       # payload corrupted in transit
    act.write_raw(bad)
    act.write_raw(flipped)
    errs = _wait_async_errors(act, n, 2)
    assert errs == [(1, "BADCS"), (1, "BADCS")]
    time.sleep(0.2)
    assert abs(h.latest().pos0 - before) <= HOLD_COUNTS, "a frame with a bad checksum moved the motor"


def test_fault_no_reply(rig):
    """Controller hung / cable half dead: bounded wait, retries, one-line error.

    The whole emulator is frozen (SIGSTOP): its simulated time stands still, so
    the driver's emulator clock counts wall-clock time once it has stood still
    for ``stall_s`` (EMULATOR_STALL_S, lowered here to keep the test short):
    every wait stays bounded."""
    h, act = rig
    assert act.clock.emulated
    act.clock.stall_s = 0.2
    h.proc.send_signal(signal.SIGSTOP)          # freeze the whole emulator
    try:
        t = time.monotonic()
        with pytest.raises(TimeoutError, match=rf"^{h.pty}: STAT: no reply within 100 ms after 2 attempt\(s\)$"):
            act.command("STAT", timeout_s=0.1, retries=1)
        dt = time.monotonic() - t
        # 2 x 100 ms of link time, which ran in wall-clock time after the first 0.2 s
        assert 0.2 <= dt < 2 * 0.1 + 0.2 + 1.0, dt
    finally:
        h.proc.send_signal(signal.SIGCONT)
    assert act.status().position == JointValues(0.0, 0.0)   # recovers, late replies ignored


def _hog_gil(seconds: float) -> None:
    """Keep every other thread of this process (the driver's reader and heartbeat
    threads too) from running for ``seconds``: what a long C call holding the GIL
    (the live reconstruction's), or a machine with more busy processes than
    cores, does to the host."""
    old = sys.getswitchinterval()
    sys.setswitchinterval(seconds + 1.0)
    try:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            pass
    finally:
        sys.setswitchinterval(old)


def _host_silence_ms(h, us0: int, us1: int) -> float:
    """Longest time (simulated ms) the MCU went without a byte from the host."""
    ts = [t for t in h.tlines_between(us0, us1) if t.flags & 8]
    assert ts, "no status lines"
    return max(t.us - t.last_rx_us for t in ts) / 1000.0


def test_host_stall_freezes_the_emulator_not_the_motors(homed_rig):
    """A host that does not run for 0.5 s does not trip the firmware's 100 ms link
    watchdog on the emulator: the last heartbeat's lease (50 ms of simulated time)
    runs out and the emulator waits for the host, so in the firmware's time the
    heartbeats stay <= ~50 ms apart."""
    h, act = homed_rig
    assert act.clock.emulated, "the driver did not attach to the emulator's clock channel"
    _moving_insertion(h, act, 40.0)
    t0 = h.latest().us
    _hog_gil(0.5)
    time.sleep(0.1)
    st = act.status()
    t1 = h.latest().us
    assert not st.watchdog_tripped and st.enabled and act.watchdog_events == 0
    silence = _host_silence_ms(h, t0, t1)
    assert silence < 0.75 * LINK_TIMEOUT_MS, f"host silent for {silence:.1f} ms of simulated time"
    assert act.clock.waits_seen >= 1, "the emulator never waited for the host"
    assert (t1 - t0) / 1000.0 < 500.0, "simulated time ran on while the host stood still"
    act.wait_settled(timeout_s=10)
    _report("host stalled 500 ms (GIL held)", f"emulator waited; longest host silence {silence:.1f} sim ms, "
            f"motors kept running")


def test_host_stall_without_lease_trips_the_watchdog(homed_rig):
    """Without the lease -- the real-time semantics of a real Uno (clock="real") --
    the same stall stops the motors after 100 ms: the emulator clock must not hide
    the safety function."""
    h, act = homed_rig
    _moving_insertion(h, act, 40.0)
    act.clock.close()                 # stop leasing: the emulator runs free in real time
    t0 = h.latest().us
    _hog_gil(0.5)
    ev = h.wait_event("S", after_us=t0, timeout_s=2)
    lat = (ev.us - int(ev.fields[0])) / 1000.0
    assert LINK_TIMEOUT_MS - 2.0 <= lat <= LINK_TIMEOUT_MS + 0.5
    with pytest.raises(ActuatorError, match="link watchdog"):
        act.wait_settled(timeout_s=2)


def test_fault_link_closed_mid_move(homed_rig):
    h, act = homed_rig
    _moving_insertion(h, act)
    t_close = h.latest().us
    act.close()                                     # cable pulled: no STOP is sent
    ev = h.wait_event("S", after_us=t_close, timeout_s=2)
    lat = _assert_stopped_after(h, ev, "link closed")
    closed = h.wait_event("C", after_us=t_close - 10_000, timeout_s=1)
    _report("link closed mid-move: PWM off after last byte received (sim ms)", f"{lat:.2f}")
    _report("link closed mid-move: PWM off after port close seen (sim ms)",
            f"{(ev.us - closed.us) / 1000:.2f}")
    assert closed.fields == ("0",)
    # last byte handed to the UART -> PWM off: the timeout is counted in 1 ms
    # ticks from the frame's completion (<= 0.2 ms after the last byte enters)
    assert LINK_TIMEOUT_MS - 2.0 <= lat <= LINK_TIMEOUT_MS + 0.5
    assert ev.us - closed.us <= LINK_TIMEOUT_MS * 1000


def test_fault_heartbeat_stopped(homed_rig):
    h, act = homed_rig
    lats = []
    for _ in range(3):
        _moving_insertion(h, act)
        t_pause = h.latest().us
        act.pause_heartbeat()
        ev = h.wait_event("S", after_us=t_pause, timeout_s=2)
        lats.append(_assert_stopped_after(h, ev, "heartbeat stopped"))
        assert act.watchdog_events >= 1
        with pytest.raises(ActuatorError, match="link watchdog"):
            act.wait_settled(timeout_s=1)
        st = act.status()
        assert st.flags & F_WDOG and not st.enabled
        act.resume_heartbeat()
        act.move_to({"insertion_mm": 2.0, "rotation_deg": 0.0}, wait=True, timeout_s=8)
        assert not act.status().watchdog_tripped
    _report("heartbeat stopped: PWM off after last byte received (sim ms)",
            ", ".join(f"{x:.2f}" for x in lats))
    assert max(lats) <= LINK_TIMEOUT_MS + 0.5 and min(lats) >= LINK_TIMEOUT_MS - 2.0


def test_fault_mcu_reset_mid_move(homed_rig):
    h, act = homed_rig
    _moving_insertion(h, act)
    t0 = h.latest().us
    h.reset_mcu()
    r = h.wait_event("R", after_us=t0 - 1, timeout_s=2)
    assert r.fields == ("signal",)
    ev = h.wait_event("S", after_us=t0 - 1, timeout_s=2)
    assert ev.us - r.us <= 1000, "motors not unpowered at reset"
    with pytest.raises(ActuatorResetError, match=r"controller reset detected .*homed again"):
        act.wait_settled(timeout_s=3)
    assert act.resets == 1
    assert act.target is None
    # re-handshake done: limits pushed again, joints not homed, motors stopped
    st = act.status()
    assert not st.homed and not st.enabled
    time.sleep(0.1)
    assert all(t.pwm0 == 0 and t.pwm1 == 0 for t in h.tlines_between(ev.us, ev.us + 100_000))
    with pytest.raises(FirmwareError, match="ERR 4 LIMIT"):
        act.command("MOV", 61000, 0)                  # LIM was pushed again
    with pytest.raises(FirmwareError, match="NOTHOMED"):
        act.move_to({"insertion_mm": 5.0, "rotation_deg": 0.0})
    act.home(timeout_s=15)
    act.move_to({"insertion_mm": 5.0, "rotation_deg": 0.0}, wait=True, timeout_s=5)
    assert h.latest().pos0 == pytest.approx(5.0 * COUNTS_PER_MM, abs=16)
    _report("MCU reset mid-move", f"PWM off {ev.us - r.us} us after reset, driver raised "
            f"ActuatorResetError, re-handshake + re-home OK")


def test_stop_and_context_manager(sim_factory):
    h = sim_factory("--x0-mm", "1")
    with ArduinoActuator(h.pty, LIMITS) as act:
        act.home(timeout_s=10)
        _moving_insertion(h, act)
        t0 = h.latest().us
    # __exit__ sent STOP: PWM off at once, not after the watchdog timeout
    ev = h.wait_event("S", after_us=t0, timeout_s=2)
    assert (ev.us - int(ev.fields[0])) / 1000 < 20


def test_closed_actuator_errors_name_port(rig):
    h, act = rig
    act.close()
    with pytest.raises(ConnectionError, match=f"{h.pty}.*STAT"):
        act.status()

