"""Serial link to a hardware correlator: the record format, a driver and a device emulator.

Record (little-endian, 40 bytes; one per measured block, and heartbeats)::

    offset size type  field
    0      2    u16   sync word 0x5AA5 (bytes A5 5A)
    2      1    u8    kind: 1 motion record, 2 heartbeat (no measurement; shows the link alive
                      and, through its sequence number, records lost at the end of a burst)
    3      1    u8    status bits: 1 valid, 2 saturated sensor, 4 pipeline overrun
    4      4    u32   sequence number (every record, either kind; +1 per record, wraps at 2^32)
    8      8    u64   timestamp, microseconds of device time
    16     4    u32   frame id
    20     2    u16   block id
    22     2    u16   reserved, 0
    24     4    f32   shift along rows, px (cur(x) ~ ref(x - d), docs/conventions.md)
    28     4    f32   shift along columns, px
    32     4    f32   peak-to-sidelobe ratio
    36     4    u32   CRC-32 (zlib / IEEE 802.3) of bytes 0..35

:class:`Driver` reads records with a timeout, resynchronises on the sync word after garbage
or a CRC error, reports every sequence number it did not receive (``Driver.stats.lost``; no
record is lost or duplicated silently) and reopens the port when it closes. :class:`PtyDevice`
serves the protocol on a pseudo-terminal (with a stable symlink, so the driver can reopen
it), with fault injection for tests.
"""

from __future__ import annotations

import contextlib
import os
import struct
import time
import tty
import zlib
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

SYNC = b"\xa5\x5a"
KIND_MOTION, KIND_HEARTBEAT = 1, 2
STATUS_VALID, STATUS_SATURATED, STATUS_OVERRUN = 1, 2, 4
_BODY = struct.Struct("<2sBBIQIHHfff")
RECORD_SIZE = _BODY.size + 4  # 40
SEQ_MOD = 2**32


class DriverError(RuntimeError):
    """The correlator link failed beyond recovery (port gone past the reconnect timeout)."""


@dataclass(frozen=True)
class Record:
    """One decoded record (see the module docstring for units)."""

    kind: int
    status: int
    seq: int
    timestamp_us: int
    frame: int
    block: int
    shift_px: tuple[float, float]
    peak: float

    @property
    def valid(self) -> bool:
        return bool(self.status & STATUS_VALID)

    def pack(self) -> bytes:
        body = _BODY.pack(SYNC, self.kind, self.status, self.seq % SEQ_MOD, self.timestamp_us,
                          self.frame, self.block, 0, *self.shift_px, self.peak)
        return body + struct.pack("<I", zlib.crc32(body))

    @classmethod
    def unpack(cls, raw: bytes) -> Record | None:
        """The record in ``raw`` (RECORD_SIZE bytes), or None when its CRC or kind is wrong."""
        body = raw[: _BODY.size]
        (crc,) = struct.unpack_from("<I", raw, _BODY.size)
        if zlib.crc32(body) != crc:
            return None
        _, kind, status, seq, ts, frame, block, _, dy, dx, peak = _BODY.unpack(body)
        if kind not in (KIND_MOTION, KIND_HEARTBEAT):
            return None
        return cls(kind, status, seq, ts, frame, block, (dy, dx), peak)


@dataclass
class LinkStats:
    """What the driver saw: good records, CRC errors, bytes skipped to resync, duplicates,
    reconnects, and every sequence number that never arrived (``lost``)."""

    records: int = 0
    crc_errors: int = 0
    garbage_bytes: int = 0
    duplicates: int = 0
    reconnects: int = 0
    lost: list[int] = field(default_factory=list)


class Parser:
    """Incremental decoder: feed bytes, get good records in order; tracks sequence gaps."""

    def __init__(self, stats: LinkStats | None = None):
        self.buf = bytearray()
        self.stats = stats or LinkStats()
        self.last_seq: int | None = None

    def feed(self, data: bytes) -> list[Record]:
        self.buf += data
        out: list[Record] = []
        while True:
            i = self.buf.find(SYNC)
            if i < 0:  # keep a trailing A5: it may start the next sync word
                keep = 1 if self.buf[-1:] == SYNC[:1] else 0
                self.stats.garbage_bytes += len(self.buf) - keep
                del self.buf[: len(self.buf) - keep]
                return out
            if i:
                self.stats.garbage_bytes += i
                del self.buf[:i]
            if len(self.buf) < RECORD_SIZE:
                return out
            rec = Record.unpack(bytes(self.buf[:RECORD_SIZE]))
            if rec is None:  # a corrupted record or a false sync: skip past this sync
                self.stats.crc_errors += 1
                del self.buf[:1]
                continue
            del self.buf[:RECORD_SIZE]
            if self._accept(rec.seq) and rec.kind == KIND_MOTION:
                self.stats.records += 1
                out.append(rec)

    def _accept(self, seq: int) -> bool:
        if self.last_seq is not None:
            gap = (seq - self.last_seq) % SEQ_MOD
            if gap == 0 or gap > SEQ_MOD // 2:  # repeated or older: never delivered twice
                self.stats.duplicates += 1
                return False
            self.stats.lost.extend((self.last_seq + j) % SEQ_MOD for j in range(1, gap))
        self.last_seq = seq
        return True


class Driver:
    """Reads image-motion records from a hardware correlator on a serial port.

    Parameters
    ----------
    port : device path or pyserial URL ('/dev/ttyUSB0', a pty symlink, 'loop://').
    baudrate : line speed (a 40-byte record takes 3.5 ms at 115200 Bd).
    timeout_s : longest wait of one read.
    reconnect_timeout_s : how long a closed port is retried before :class:`DriverError`.
    """

    def __init__(self, port: str, baudrate: int = 115200, timeout_s: float = 0.05,
                 reconnect_timeout_s: float = 5.0):
        self.port, self.baudrate = str(port), int(baudrate)
        self.timeout_s, self.reconnect_timeout_s = float(timeout_s), float(reconnect_timeout_s)
        self.stats = LinkStats()
        self.parser = Parser(self.stats)
        self._ser = None
        self._open()

    def _open(self) -> None:
        import serial

        self._ser = serial.serial_for_url(self.port, baudrate=self.baudrate,
                                          timeout=self.timeout_s)

    def close(self) -> None:
        if self._ser is not None:
            with contextlib.suppress(Exception):
                self._ser.close()
            self._ser = None

    def __enter__(self) -> Driver:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _reconnect(self) -> None:
        import serial

        self.close()
        deadline = time.monotonic() + self.reconnect_timeout_s
        while True:
            try:
                self._open()
                self.stats.reconnects += 1
                return
            except (serial.SerialException, OSError) as e:
                if time.monotonic() > deadline:
                    raise DriverError(f"correlator port {self.port} is gone and did not come "
                                      f"back within {self.reconnect_timeout_s:g} s: {e}; check "
                                      f"the cable and the device's power") from None
                time.sleep(min(0.05, self.reconnect_timeout_s / 10))

    def read(self, timeout_s: float | None = None) -> list[Record]:
        """Records that arrive within ``timeout_s`` (default: one read timeout); may be empty."""
        import serial

        deadline = time.monotonic() + (self.timeout_s if timeout_s is None else timeout_s)
        out: list[Record] = []
        while True:
            try:
                n = max(1, self._ser.in_waiting)
                data = self._ser.read(min(n, 65536))
            except (serial.SerialException, OSError):
                self._reconnect()
                data = b""
            if data:
                out += self.parser.feed(data)
            if (out and not self._ser.in_waiting) or time.monotonic() >= deadline:
                return out

    def read_until(self, done, timeout_s: float) -> list[Record]:
        """Read until ``done(records so far, parser)`` is true or ``timeout_s`` passes."""
        deadline = time.monotonic() + timeout_s
        out: list[Record] = []
        while time.monotonic() < deadline:
            out += self.read(min(self.timeout_s, max(0.0, deadline - time.monotonic())))
            if done(out, self.parser):
                break
        return out


class PtyDevice:
    """A correlator serving records on a pseudo-terminal, reachable at the symlink ``link``.

    Faults for tests: ``corrupt_probability`` flips one byte of a record,
    ``drop_probability`` loses a record (its sequence number is still used),
    ``garbage_probability`` writes random bytes before a record. ``reopen()`` closes the port
    (the driver sees it go) and opens a new one behind the same link.
    """

    def __init__(self, link: str | Path, rng: np.random.Generator | None = None,
                 corrupt_probability: float = 0.0, drop_probability: float = 0.0,
                 garbage_probability: float = 0.0):
        for name, p in (("corrupt_probability", corrupt_probability),
                        ("drop_probability", drop_probability),
                        ("garbage_probability", garbage_probability)):
            if not 0.0 <= p < 1.0:
                raise ValueError(f"{name} must be in [0, 1), got {p}")
        self.link = Path(link)
        self.rng = rng if rng is not None else np.random.default_rng(0)
        self.p_corrupt, self.p_drop, self.p_garbage = (corrupt_probability, drop_probability,
                                                       garbage_probability)
        self.seq = 0
        self.sent: list[int] = []  # sequence numbers written intact
        self._master = self._slave = None
        self._open()

    def _open(self) -> None:
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)  # no line discipline: bytes pass unchanged
        tmp = self.link.with_name(self.link.name + ".tmp")
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
        tmp.symlink_to(os.ttyname(self._slave))
        os.replace(tmp, self.link)  # atomic: the driver never sees a missing link

    def close(self) -> None:
        for fd in (self._master, self._slave):
            if fd is not None:
                with contextlib.suppress(OSError):
                    os.close(fd)
        self._master = self._slave = None

    def remove_link(self) -> None:
        with contextlib.suppress(FileNotFoundError):
            self.link.unlink()

    def reopen(self) -> None:
        self.close()
        self._open()

    def __enter__(self) -> PtyDevice:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
        self.remove_link()

    def _write(self, data: bytes) -> None:
        view = memoryview(data)
        while view:
            n = os.write(self._master, view)
            view = view[n:]

    def send(self, records: Iterable[Record]) -> None:
        """Number (seq) and write records, applying the fault probabilities."""
        chunks = []
        for rec in records:
            rec = Record(rec.kind, rec.status, self.seq, rec.timestamp_us, rec.frame, rec.block,
                         rec.shift_px, rec.peak)
            self.seq += 1
            u = self.rng.random(3)
            if u[0] < self.p_garbage:
                chunks.append(self.rng.integers(0, 256, int(self.rng.integers(1, 64)),
                                                np.uint8).tobytes())
            if u[1] < self.p_drop:
                continue
            raw = bytearray(rec.pack())
            if u[2] < self.p_corrupt:
                i = int(self.rng.integers(0, RECORD_SIZE))
                raw[i] ^= 1 << int(self.rng.integers(0, 8))
            else:
                self.sent.append(rec.seq)
            chunks.append(bytes(raw))
        if chunks:
            self._write(b"".join(chunks))

    def heartbeat(self, timestamp_us: int = 0) -> None:
        self.send([Record(KIND_HEARTBEAT, 0, 0, timestamp_us, 0, 0, (0.0, 0.0), 0.0)])

    def skip(self, n: int) -> None:
        """Lose n records (sequence numbers used, nothing written), as while the port is down."""
        self.seq += int(n)


def motion_records(frame: int, t_us: np.ndarray, shift_px: np.ndarray, valid: np.ndarray,
                   peak: np.ndarray, blocks: np.ndarray | None = None) -> list[Record]:
    """Motion records of one frame's blocks (ids ``blocks``, default 0..n-1); the device sets
    the sequence numbers when it sends them."""
    ids = np.arange(len(valid)) if blocks is None else np.asarray(blocks)
    return [Record(KIND_MOTION, STATUS_VALID if valid[i] else 0, 0, int(t_us[i]), int(frame),
                   int(ids[i]), (float(shift_px[i, 0]), float(shift_px[i, 1])), float(peak[i]))
            for i in range(len(valid))]


class LoopbackLink:
    """A device emulator on a pty and a driver reading it, in one process: a scenario's loop
    sends each frame's results through the serial protocol and uses what the driver decodes.
    Records lost on the way (``drop_probability``, ``corrupt_probability``) come back as
    missing: those blocks are invalid for that frame."""

    def __init__(self, rng: np.random.Generator, corrupt_probability: float = 0.0,
                 drop_probability: float = 0.0):
        import tempfile

        self._dir = tempfile.TemporaryDirectory(prefix="imc-link-")
        self.device = PtyDevice(Path(self._dir.name) / "jtoc", rng, corrupt_probability,
                                drop_probability)
        self.driver = Driver(str(self.device.link), timeout_s=0.01)
        self.heartbeats: set[int] = set()

    def roundtrip(self, frame: int, t_us: np.ndarray, blocks: np.ndarray, shift_px: np.ndarray,
                  valid: np.ndarray, peak: np.ndarray):
        """Send records of ``blocks`` (n,) and read them back: (shift (n, 2), valid (n,),
        peak (n,), received (n,)) as decoded; missing records give NaN, False, 0, False."""
        self.device.send(motion_records(frame, t_us, shift_px, valid, peak, blocks))
        self.heartbeats.add(self.device.seq)
        self.device.heartbeat(int(t_us.max()) if len(t_us) else 0)
        last = self.device.seq - 1
        got = self.driver.read_until(lambda _o, p: p.last_seq == last, timeout_s=2.0)
        pos = {int(b): i for i, b in enumerate(blocks)}
        n = len(blocks)
        out_s, out_v = np.full((n, 2), np.nan), np.zeros(n, bool)
        out_p, rec = np.zeros(n), np.zeros(n, bool)
        for r in got:
            i = pos.get(r.block)
            if r.frame == frame and i is not None:
                out_s[i], out_v[i], out_p[i], rec[i] = r.shift_px, r.valid, r.peak, True
        return out_s, out_v, out_p, rec

    def stats(self) -> dict:
        """The driver's counters; ``lost`` counts motion records, heartbeats apart."""
        st = self.driver.stats
        hb = sum(1 for q in st.lost if q in self.heartbeats)
        return {"records": st.records, "lost": len(st.lost) - hb, "heartbeats_lost": hb,
                "crc_errors": st.crc_errors, "garbage_bytes": st.garbage_bytes,
                "duplicates": st.duplicates, "reconnects": st.reconnects}

    def state(self) -> dict[str, np.ndarray]:
        """What a resumed run needs to continue this link exactly: the driver's counters and
        the sequence number it expects, the device's next sequence number and its fault
        generator, and which sequence numbers were heartbeats."""
        import json

        st, parser = self.driver.stats, self.driver.parser
        return {"records": np.array(st.records), "crc_errors": np.array(st.crc_errors),
                "garbage_bytes": np.array(st.garbage_bytes),
                "duplicates": np.array(st.duplicates), "reconnects": np.array(st.reconnects),
                "lost": np.array(st.lost, np.int64),
                "heartbeats": np.array(sorted(self.heartbeats), np.int64),
                "seq": np.array(self.device.seq),
                "last_seq": np.array(-1 if parser.last_seq is None else parser.last_seq),
                "rng": np.array(json.dumps(self.device.rng.bit_generator.state))}

    def restore(self, state: dict[str, np.ndarray]) -> None:
        """Continue from :meth:`state` (a KeyError if it lacks a part)."""
        import json

        st, parser = self.driver.stats, self.driver.parser
        for name in ("records", "crc_errors", "garbage_bytes", "duplicates", "reconnects"):
            setattr(st, name, int(state[name]))
        st.lost = [int(q) for q in state["lost"]]
        self.heartbeats = {int(q) for q in state["heartbeats"]}
        self.device.seq = int(state["seq"])
        last = int(state["last_seq"])
        parser.last_seq = None if last < 0 else last
        self.device.rng.bit_generator.state = json.loads(str(state["rng"]))

    def close(self) -> None:
        self.driver.close()
        self.device.close()
        self._dir.cleanup()
