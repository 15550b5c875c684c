"""ArduPilot SITL helpers shared by the autopilot-in-the-loop tests
(`test_sitl*.py`): the SITL process, the test's GCS link to it, and a TCP
tap in front of SERIAL1 that records (and can black out) what star sends.

The SITL binary is `$STAR_SITL_DIR/arducopter` (default `../shared/sitl`
beside the repository); `SKIP` skips a test module without it.
"""

import math
import os
import pathlib
import shutil
import socket
import subprocess
import threading
import time

import pytest

from conftest import REPO

os.environ["MAVLINK20"] = "1"
from pymavlink import mavutil  # noqa: E402

SITL_DIR = pathlib.Path(os.environ.get("STAR_SITL_DIR", REPO.parent / "shared" / "sitl"))
ARDUCOPTER = SITL_DIR / "arducopter"
HOME = "-35.363261,149.165230,584,0"
SOCAT = shutil.which("socat")

SKIP = pytest.mark.skipif(
    not ARDUCOPTER.exists(),
    reason=f"ArduPilot SITL not found at {ARDUCOPTER} (set STAR_SITL_DIR); autopilot-in-the-loop tests skipped",
)


def ports_free(instance):
    for port in (5760 + 10 * instance, 5762 + 10 * instance):
        with socket.socket() as s:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            try:
                s.bind(("127.0.0.1", port))
            except OSError:
                return False
    return True


def free_instance():
    """A SITL instance number (-I) whose ports are free, away from 0 (the
    README's default, perhaps in use by someone else)."""
    start = 20 + os.getpid() % 40
    for k in range(60):
        instance = 20 + (start + k) % 60
        if ports_free(instance):
            return instance
    raise AssertionError("no free SITL instance ports")


class Gcs:
    """The test's pymavlink link to SERIAL0: STATUSTEXT, LOCAL_POSITION_NED
    and ATTITUDE, each with its arrival time (CLOCK_MONOTONIC, s), and the
    messages of the types in `keep` (the autopilot's HEARTBEAT included) as
    (arrival time, message) in `kept[type]`.

    One thread reads the link; nothing else calls `recv_match` on it (a
    second reader, such as `wait_heartbeat`, would take messages away from
    the recorded ones: a CI run lost EKF3's tilt-alignment STATUSTEXT so)."""

    def __init__(self, port, keep=()):
        end = time.monotonic() + 20
        while True:
            try:
                self.conn = mavutil.mavlink_connection(
                    f"tcp:127.0.0.1:{port}", source_system=255, source_component=190,
                    dialect="common", robust_parsing=True)
                break
            except OSError:
                if time.monotonic() > end:
                    raise
                time.sleep(0.1)
        self.texts = []
        self.positions = []
        self.attitudes = []
        self.kept = {kind: [] for kind in keep}
        self.heartbeat = threading.Event()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self):
        while not self._stop.is_set():
            try:
                m = self.conn.recv_match(blocking=True, timeout=0.1)
            except (OSError, ConnectionError):
                return
            if m is None:
                continue
            t = time.monotonic()
            kind = m.get_type()
            if kind == "HEARTBEAT" and m.get_srcSystem() != 255:
                self.heartbeat.set()
                if kind in self.kept:
                    self.kept[kind].append((t, m))
            elif kind == "STATUSTEXT":
                self.texts.append((t, m.text))
            elif kind == "LOCAL_POSITION_NED":
                self.positions.append((t, (m.x, m.y, m.z)))
            elif kind == "ATTITUDE":
                self.attitudes.append((t, m.yaw))
            elif kind in self.kept and kind != "HEARTBEAT":
                self.kept[kind].append((t, m))

    def start_streams(self):
        assert self.heartbeat.wait(timeout=20), "no HEARTBEAT from SITL in 20 s"
        self.conn.mav.request_data_stream_send(
            self.conn.target_system, self.conn.target_component,
            mavutil.mavlink.MAV_DATA_STREAM_ALL, 10, 1)
        for msg_id in (mavutil.mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED, mavutil.mavlink.MAVLINK_MSG_ID_ATTITUDE):
            self.conn.mav.command_long_send(
                self.conn.target_system, self.conn.target_component,
                mavutil.mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0, msg_id, 20_000, 0, 0, 0, 0, 0)

    def wait_text(self, needle, timeout_s):
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            for t, text in self.texts:
                if needle in text:
                    return t
            time.sleep(0.05)
        raise AssertionError(f"no STATUSTEXT `{needle}` in {timeout_s} s: {[x for _, x in self.texts]}")

    def close(self):
        self._stop.set()
        self._thread.join(timeout=2)
        self.conn.close()


class Tap:
    """A TCP tap: star connects here, the tap connects to SITL's SERIAL1 and
    copies bytes both ways as they come; what star sends is also decoded
    (arrival time, message type, fields).

    With `frame_wise=True` both directions are forwarded as whole MAVLink
    frames (as parsed), and while `blackout` is set nothing is forwarded
    either way: a link outage. What star sent then is in `dropped`."""

    def __init__(self, upstream_port, frame_wise=False):
        self.upstream_port = upstream_port
        self.frame_wise = frame_wise
        self.blackout = threading.Event()
        self.dropped = []
        self.listener = socket.socket()
        self.listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.listener.bind(("127.0.0.1", 0))
        self.listener.listen(1)
        self.listener.settimeout(0.2)
        self.port = self.listener.getsockname()[1]
        self.messages = []
        self._stop = threading.Event()
        self._threads = [threading.Thread(target=self._accept, daemon=True)]
        self._threads[0].start()

    def _accept(self):
        while not self._stop.is_set():
            try:
                star, _ = self.listener.accept()
            except socket.timeout:
                continue
            sitl = socket.create_connection(("127.0.0.1", self.upstream_port), timeout=5)
            for s in (star, sitl):
                s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                s.settimeout(0.2)
            parsers = []
            for _ in range(2):
                parser = mavutil.mavlink.MAVLink(None)
                parser.robust_parsing = True
                parsers.append(parser)
            for src, dst, p, from_star in ((star, sitl, parsers[0], True),
                                           (sitl, star, parsers[1] if self.frame_wise else None, False)):
                t = threading.Thread(target=self._pump, args=(src, dst, p, from_star), daemon=True)
                t.start()
                self._threads.append(t)

    def _pump(self, src, dst, parser, from_star):
        while not self._stop.is_set():
            try:
                data = src.recv(65536)
            except socket.timeout:
                continue
            except OSError:
                break
            if not data:
                break
            if not self.frame_wise:
                try:
                    dst.sendall(data)
                except OSError:
                    break
                if parser is None:
                    continue
            t = time.monotonic()
            out = bytearray()
            for m in parser.parse_buffer(data) or []:
                dropping = self.blackout.is_set()
                if self.frame_wise and not dropping:
                    out += m.get_msgbuf()
                if not from_star or m.get_type() == "BAD_DATA":
                    continue
                (self.dropped if self.frame_wise and dropping else self.messages).append(
                    (t, m.get_type(), m.to_dict()))
            if out:
                try:
                    dst.sendall(bytes(out))
                except OSError:
                    break
        for s in (src, dst):
            try:
                s.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass

    def of_type(self, name):
        return [(t, f) for t, kind, f in self.messages if kind == name]

    def close(self):
        self._stop.set()
        for t in self._threads:
            t.join(timeout=2)
        self.listener.close()


class Sitl:
    """ArduCopter SITL in its own working directory (eeprom.bin, logs/)."""

    def __init__(self, instance, workdir, serial1=None, extra_args=(), params=None):
        """`serial1`: SITL's SERIAL1 on this serial device (`uart:PATH:BAUD`)
        instead of TCP port 5762 + 10 N. `params`: more default parameters
        ({name: value}, after copter.parm and extnav.parm)."""
        self.instance = instance
        self.dir = workdir
        self.dir.mkdir(parents=True, exist_ok=True)
        self.log = open(self.dir / "sitl.out", "w")
        defaults = [str(SITL_DIR / "copter.parm"), str(SITL_DIR / "extnav.parm")]
        if params:
            extra = self.dir / "harness.parm"
            extra.write_text("".join(f"{k} {v}\n" for k, v in params.items()))
            defaults.append(str(extra))
        args = [str(ARDUCOPTER), "--model", "quad", "--speedup", "1", f"-I{instance}", "--wipe",
                "--home", HOME, "--defaults", ",".join(defaults)]
        if serial1:
            args += ["--serial1", serial1]
        self.proc = subprocess.Popen([*args, *extra_args], cwd=self.dir, stdout=self.log,
                                     stderr=subprocess.STDOUT)
        self.gcs_port = 5760 + 10 * instance
        self.serial1_port = 5762 + 10 * instance

    def stop(self):
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self.log.close()

    def log_rows(self, types):
        """Records of the given types from SITL's dataflash log, as dicts
        (empty where there is no log)."""
        logs = sorted((self.dir / "logs").glob("*.BIN"))
        if not logs:
            return []
        log = mavutil.mavlink_connection(str(logs[-1]))
        rows = []
        while True:
            m = log.recv_match(type=list(types))
            if m is None:
                return rows
            rows.append({"type": m.get_type(), **m.to_dict()})

    def vision_log(self):
        """VISP records of SITL's dataflash log: (TimeUS, RTimeUS, CTimeMS,
        Ign), or None where the log cannot be read."""
        logs = sorted((self.dir / "logs").glob("*.BIN"))
        if not logs:
            return None
        try:
            log = mavutil.mavlink_connection(str(logs[-1]))
            rows = []
            while True:
                m = log.recv_match(type="VISP")
                if m is None:
                    break
                rows.append((m.TimeUS, m.RTimeUS, m.CTimeMS, getattr(m, "Ign", 0)))
            return rows
        except Exception as e:  # noqa: BLE001 - a figure, not a check
            print(f"SITL log not readable: {e}")
            return None


def stop_all(sitl, rig, *closers):
    """Tears one start down: each closer that was made (a Tap, a Gcs), then
    star's rig, then SITL."""
    for closer in closers:
        if closer is not None:
            closer.close()
    rig.cleanup()
    sitl.stop()


def yaw_of(fields):
    if "yaw" in fields:
        return fields["yaw"]
    w, x, y, z = fields["q"]
    return math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


def angle_deg(a, b):
    return abs(math.degrees(math.atan2(math.sin(a - b), math.cos(a - b))))


class PtyPair:
    """`socat` joining two ptys; `a` and `b` are their /dev/pts paths."""

    def __init__(self, workdir):
        self.a_link = workdir / "pty_sitl"
        self.b_link = workdir / "pty_star"
        self.proc = subprocess.Popen(
            [SOCAT, "-d", "-d", f"pty,raw,echo=0,link={self.a_link}", f"pty,raw,echo=0,link={self.b_link}"],
            stdout=subprocess.DEVNULL, stderr=open(workdir / "socat.out", "w"))
        end = time.monotonic() + 10
        while not (self.a_link.exists() and self.b_link.exists()):
            assert self.proc.poll() is None, (workdir / "socat.out").read_text()
            assert time.monotonic() < end, "socat made no pty pair in 10 s"
            time.sleep(0.05)
        self.a = os.path.realpath(self.a_link)
        self.b = os.path.realpath(self.b_link)

    def drain_b(self):
        """Reads and discards what waits on `b` (what SITL wrote before the
        reader opened it); returns the byte count."""
        fd = os.open(self.b, os.O_RDONLY | os.O_NONBLOCK | os.O_NOCTTY)
        n = 0
        try:
            while True:
                try:
                    chunk = os.read(fd, 65536)
                except BlockingIOError:
                    return n
                if not chunk:
                    return n
                n += len(chunk)
        finally:
            os.close(fd)

    def close(self):
        if self.proc.poll() is None:
            self.proc.terminate()
            self.proc.wait(timeout=5)


def dataflash(sitl_dir):
    """(VISP rows (TimeUS, (PX, PY, PZ)), MSG rows (TimeUS, text)) of SITL's log."""
    logs = sorted((sitl_dir / "logs").glob("*.BIN"))
    assert logs, f"no SITL dataflash log in {sitl_dir / 'logs'}"
    log = mavutil.mavlink_connection(str(logs[-1]))
    visp, msgs = [], []
    while True:
        m = log.recv_match(type=["VISP", "MSG"])
        if m is None:
            break
        if m.get_type() == "VISP":
            visp.append((m.TimeUS, (m.PX, m.PY, m.PZ)))
        else:
            msgs.append((m.TimeUS, m.Message))
    return visp, msgs
