"""Fixtures for the firmware-in-the-loop tests (tests/test_firmware.py).

* ``fil_build``   (session): builds rig/hw/firmware and rig/hw/sim with make into a
  temporary directory; skips only when avr-gcc is not installed.
* ``sim_factory`` (function): starts ``ctr_sim`` (the firmware on an emulated
  ATmega328P with the motor/encoder plants, serial port on a pty) and returns
  a :class:`SimHarness` that parses the harness' stdout.  Every harness is
  terminated at the end of the test.

Import the fixtures in a test module with ``from fil_fixtures import *``.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
FW_DIR = ROOT / "rig" / "hw" / "firmware"
SIM_DIR = ROOT / "rig" / "hw" / "sim"

__all__ = ["fil_build", "sim_factory", "SimHarness", "FilBuild", "TLine"]


@dataclass(frozen=True)
class FilBuild:
    elf: Path
    hex: Path
    sim: Path


@dataclass(frozen=True)
class TLine:
    """``T <us> <pos0> <pos1> <pwm0> <pwm1> <last_rx_us> <flags>``"""

    us: int
    pos0: int
    pos1: int
    pwm0: int
    pwm1: int
    last_rx_us: int
    flags: int


@dataclass(frozen=True)
class Event:
    kind: str            # S, M, C, R, Q
    us: int
    fields: tuple[str, ...]
    wall: float          # time.monotonic() when read


class SimHarness:
    """A running ``ctr_sim`` process and the parsed stream of its stdout."""

    def __init__(self, build: FilBuild, *args: str, tmp_path: Path, start_timeout_s: float = 10.0):
        self._stderr_path = tmp_path / f"ctr_sim_{os.getpid()}_{time.monotonic_ns()}.stderr"
        self._stderr = open(self._stderr_path, "w+")
        self.proc = subprocess.Popen([str(build.sim), *args, str(build.elf)],
                                     stdout=subprocess.PIPE, stderr=self._stderr,
                                     text=True, bufsize=1)
        self._cond = threading.Condition()
        self.tlines: list[TLine] = []
        self.events: list[Event] = []
        self.pty: str | None = None
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()
        with self._cond:
            if not self._cond.wait_for(lambda: self.pty is not None or self.proc.poll() is not None,
                                       start_timeout_s):
                raise RuntimeError(f"ctr_sim did not print its PTY line within {start_timeout_s}s")
        if self.pty is None:
            raise RuntimeError(f"ctr_sim exited early (rc={self.proc.returncode}): {self.stderr()}")

    def _read(self):
        for line in self.proc.stdout:
            parts = line.split()
            if not parts:
                continue
            now = time.monotonic()
            with self._cond:
                k = parts[0]
                if k == "PTY":
                    self.pty = parts[1]
                elif k == "T" and len(parts) >= 8:
                    self.tlines.append(TLine(*(int(x) for x in parts[1:8])))
                    if len(self.tlines) > 200_000:
                        del self.tlines[:100_000]
                else:
                    us = int(parts[1]) if len(parts) > 1 and parts[1].isdigit() else -1
                    self.events.append(Event(k, us, tuple(parts[2:]), now))
                self._cond.notify_all()
        with self._cond:
            self._cond.notify_all()

    # -- queries ------------------------------------------------------------
    def latest(self, timeout_s: float = 2.0) -> TLine:
        """The newest T line (waits for a first one)."""
        with self._cond:
            if not self._cond.wait_for(lambda: self.tlines, timeout_s):
                raise TimeoutError("no status line from ctr_sim")
            return self.tlines[-1]

    def next_tline(self, timeout_s: float = 2.0) -> TLine:
        """A T line printed after this call."""
        with self._cond:
            n = len(self.tlines)
            if not self._cond.wait_for(lambda: len(self.tlines) > n, timeout_s):
                raise TimeoutError("no status line from ctr_sim")
            return self.tlines[-1]

    def wait_event(self, kind: str, after_us: int = -1, timeout_s: float = 3.0) -> Event:
        """First event of ``kind`` with simulated time > after_us."""
        def find():
            return next((e for e in self.events if e.kind == kind and e.us > after_us), None)
        with self._cond:
            if not self._cond.wait_for(lambda: find() is not None or self.proc.poll() is not None,
                                       timeout_s) or find() is None:
                raise TimeoutError(f"no {kind!r} event after {after_us} us within {timeout_s}s "
                                   f"(events: {self.events[-8:]})")
            return find()

    def wait_tline(self, pred, timeout_s: float = 3.0) -> TLine:
        """First T line (from now on) satisfying ``pred``."""
        with self._cond:
            start = len(self.tlines)
            def find():
                return next((t for t in self.tlines[start:] if pred(t)), None)
            if not self._cond.wait_for(lambda: find() is not None, timeout_s):
                raise TimeoutError(f"no matching status line within {timeout_s}s "
                                   f"(last: {self.tlines[-1] if self.tlines else None})")
            return find()

    def tlines_between(self, us0: int, us1: int) -> list[TLine]:
        with self._cond:
            return [t for t in self.tlines if us0 <= t.us <= us1]

    def stderr(self) -> str:
        self._stderr.flush()
        try:
            return self._stderr_path.read_text()[-2000:]
        except OSError:
            return ""

    # -- control --------------------------------------------------------------
    def reset_mcu(self) -> None:
        """Reset the emulated MCU (SIGUSR1), like the Uno's reset button."""
        self.proc.send_signal(signal.SIGUSR1)

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(5)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)
        self._reader.join(2)
        self._stderr.close()


@pytest.fixture(scope="session")
def fil_build(tmp_path_factory) -> FilBuild:
    if shutil.which("avr-gcc") is None:
        pytest.skip("avr-gcc not installed (apt-get install gcc-avr avr-libc binutils-avr "
                    "simavr libsimavr-dev libelf-dev): firmware-in-the-loop tests skipped")
    out = tmp_path_factory.mktemp("fil")
    for d, b in ((FW_DIR, out / "fw"), (SIM_DIR, out / "sim")):
        r = subprocess.run(["make", "-C", str(d), f"BUILD={b}"], capture_output=True, text=True)
        if r.returncode != 0:
            raise RuntimeError(f"make -C {d} failed:\n{r.stdout[-3000:]}\n{r.stderr[-3000:]}")
    build = FilBuild(out / "fw" / "ctr_actuator.elf", out / "fw" / "ctr_actuator.hex",
                     out / "sim" / "ctr_sim")
    for p in (build.elf, build.hex, build.sim):
        assert p.exists(), p
    return build


@pytest.fixture
def sim_factory(fil_build, tmp_path):
    started: list[SimHarness] = []

    def start(*args: str) -> SimHarness:
        h = SimHarness(fil_build, *args, tmp_path=tmp_path)
        started.append(h)
        return h

    yield start
    for h in started:
        h.close()
