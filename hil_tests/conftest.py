"""Fixtures of the hardware-in-the-loop harness.

The harness runs `star camera` (a replay of a synthetic dataset) and
`star track` as separate processes, each test on its own iceoryx2 resource
prefix, and plays the autopilot itself: a pymavlink endpoint (udpin on the
harness side, udpout from star) that receives HEARTBEAT and
VISION_POSITION_ESTIMATE, sends HEARTBEAT and TIMESYNC requests, and answers
star's TIMESYNC requests with CLOCK_MONOTONIC (so `usec` stays in the
capture clock).

Datasets are generated once per session with `target/release/star synth`
from fixed seeds; build the binary first (`make build`).
"""

import itertools
import os
import pathlib
import shutil
import signal
import socket
import subprocess
import threading
import time

import numpy as np
import pytest

os.environ["MAVLINK20"] = "1"
from pymavlink import mavutil  # noqa: E402

mavutil.set_dialect("common")

REPO = pathlib.Path(__file__).resolve().parent.parent
# The release binary: STAR_BIN, else where cargo put it (CARGO_TARGET_DIR, as
# scripts/test.sh leaves it in the environment), else target/release/star.
_TARGET = REPO / os.environ.get("CARGO_TARGET_DIR", "target")  # relative: to the repo
STAR = pathlib.Path(os.environ.get("STAR_BIN", _TARGET / "release" / "star"))
SEED = 3
FRAMES = 150
FPS = 50.0
# Replay speed factor of the camera (STAR_HIL_SPEED, default 1 = 50 Hz). On a
# machine too loaded to track at 50 Hz, 0.5 runs every scenario at 25 Hz.
SPEED = float(os.environ.get("STAR_HIL_SPEED", "1"))
_counter = itertools.count()


def pytest_configure(config):
    config.addinivalue_line("markers", "soak: long-running soak test (STAR_SOAK_S seconds)")


@pytest.fixture(scope="session")
def star_bin():
    if not STAR.exists():
        pytest.fail(f"{STAR} not found: run `cargo build --release` (or `make build`) first")
    return STAR


@pytest.fixture(scope="session")
def dataset(star_bin, tmp_path_factory):
    """A 150-frame `realistic` sequence (3 s at 50 Hz), seed 3."""
    out = tmp_path_factory.mktemp("data") / "realistic"
    subprocess.run(
        [str(star_bin), "--log", "warn", "synth", "--preset", "realistic", str(out),
         "--frames", str(FRAMES), "--seed", str(SEED), "--no-depth"],
        check=True, timeout=300,
    )
    return out


@pytest.fixture(scope="session")
def reloc_db(star_bin, dataset):
    """The relocalization database of the dataset's map (`star reloc build`),
    its grid views at the flight's mean height only (the default grid has
    three heights: 72 s to build on 2 cores against 35 s, docs/ci.md)."""
    db = dataset / "map.reloc"
    if not db.exists():
        _, gt = read_tum(dataset / "groundtruth.txt")
        config = dataset / "reloc-build.toml"
        config.write_text(f"[reloc]\nheights_m = [{gt[:, 2].mean():.2f}]\n")
        subprocess.run(
            [str(star_bin), "--log", "warn", "reloc", "build", "--config", str(config),
             "--map", str(dataset / "map" / "map.obj"),
             "--camera", str(dataset / "camera.toml"), "-o", str(db)],
            check=True, timeout=600,
        )
    return db


def read_tum(path):
    """TUM trajectory -> (stamps (N,), poses (N, 7) as tx ty tz qx qy qz qw)."""
    rows = [line.split() for line in open(path) if line.strip() and not line.startswith("#")]
    data = np.array([[float(v) for v in r] for r in rows])
    return data[:, 0], data[:, 1:8]


def write_subset(src, dst, order, black=()):
    """A dataset at `dst` playing the frames of `src` in `order` (indices), at
    50 Hz; images and map are linked, not copied. Positions listed in `black`
    show an all-black image instead (a blackout: the camera still moves)."""
    dst.mkdir(parents=True, exist_ok=True)
    rgb = [line.split() for line in open(src / "rgb.txt") if line.strip() and not line.startswith("#")]
    stamps, poses = read_tum(src / "groundtruth.txt")
    t0 = float(rgb[0][0])
    black = set(black)
    if black:
        import cv2
        shape = cv2.imread(str(src / rgb[0][1]), cv2.IMREAD_GRAYSCALE).shape
        assert cv2.imwrite(str(dst / "black.png"), np.zeros(shape, np.uint8))
    with open(dst / "rgb.txt", "w") as f:
        for i, k in enumerate(order):
            image = dst / "black.png" if i in black else src / rgb[k][1]
            f.write(f"{t0 + i / FPS:.6f} {image}\n")
    with open(dst / "groundtruth.txt", "w") as f:
        for i, k in enumerate(order):
            f.write(f"{t0 + i / FPS:.6f} " + " ".join(f"{v:.9f}" for v in poses[k]) + "\n")
    shutil.copy(src / "camera.toml", dst / "camera.toml")
    if not (dst / "map").exists():
        (dst / "map").symlink_to(src / "map")
    return dst


def pingpong(dataset, dst, frames):
    """`frames` frames of the sequence played forward, backward, forward...:
    continuous motion for as long as needed, without `--loop` (whose wrap
    is a jump the tracker cannot follow without relocalization)."""
    bounce = list(range(FRAMES)) + list(range(FRAMES - 2, 0, -1))
    order = (bounce * (frames // len(bounce) + 1))[:frames]
    return write_subset(dataset, dst, order)


def free_udp_port():
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


# The transforms the harness configures (and inverts with its own code).
NED_FROM_WORLD = {"translation_m": [1.0, -2.0, 0.5], "rpy_deg": [180.0, 0.0, 90.0]}
BODY_FROM_CAMERA = {"translation_m": [0.1, 0.0, 0.05], "rpy_deg": [90.0, 0.0, 90.0]}


class Rig:
    """One test's isolated configuration and the star processes it started."""

    def __init__(self, star_bin, tmp, dataset):
        self.star = str(star_bin)
        self.tmp = tmp
        self.dataset = dataset
        self.prefix = f"hil{os.getpid()}x{next(_counter)}_"
        self.port = free_udp_port()
        self.procs = []
        text = (REPO / "config" / "iceoryx2.toml").read_text()
        assert 'prefix = "iox2_"' in text
        self.iox = tmp / "iceoryx2.toml"
        self.iox.write_text(text.replace('prefix = "iox2_"', f'prefix = "{self.prefix}"'))
        self.config = tmp / "star.toml"
        self.write_config()

    def write_config(self, extra="", camera_lines=None, init_pose=None, ned_from_world=None,
                     body_from_camera=None, tracker=""):
        """The test's star.toml. By default: the dataset's camera and first
        ground-truth pose, the harness's transforms; each can be replaced
        (`camera_lines`: the `[camera.intrinsics]` body, TOML lines;
        `tracker`: more `[tracker]` lines)."""
        cam = []
        for line in (self.dataset / "camera.toml").read_text().splitlines():
            if line.startswith("depth_scale"):
                continue
            cam.append(line.replace("[distortion]", "[camera.intrinsics.distortion]"))
        if camera_lines is not None:
            cam = camera_lines
        if init_pose is None:
            _, poses = read_tum(self.dataset / "groundtruth.txt")
            init_pose = poses[0]
        init = ", ".join(f"{v:.12f}" for v in init_pose)
        ned_from_world = ned_from_world or NED_FROM_WORLD
        body_from_camera = body_from_camera or BODY_FROM_CAMERA
        fmt = lambda v: "[" + ", ".join(str(x) for x in v) + "]"  # noqa: E731
        self.config.write_text(
            f"""[ipc]
iceoryx2_config = "{self.iox}"
silence_timeout_ms = 200
[map]
mesh = "{self.dataset / 'map' / 'map.obj'}"
[tracker]
init_pose = [{init}]
{tracker}
[mavlink]
connection = "udpout:127.0.0.1:{self.port}"
# rate_hz stays at its default, 50 Hz: the camera's own rate.
[mavlink.ned_from_world]
translation_m = {fmt(ned_from_world['translation_m'])}
rpy_deg = {fmt(ned_from_world['rpy_deg'])}
[mavlink.body_from_camera]
translation_m = {fmt(body_from_camera['translation_m'])}
rpy_deg = {fmt(body_from_camera['rpy_deg'])}
{extra}
[camera.intrinsics]
""" + "\n".join(cam) + "\n"
        )

    def spawn(self, args, name, log_filter="info"):
        log = open(self.tmp / f"{name}.log", "w")
        p = subprocess.Popen([self.star, "--log", log_filter, *args], stdout=subprocess.PIPE,
                             stderr=log, text=True, env={**os.environ, "NO_COLOR": "1"})
        p.log_path = self.tmp / f"{name}.log"
        self.procs.append(p)
        return p

    def start_tracker(self, *extra):
        p = self.spawn(["track", "--config", str(self.config), *extra], "track")
        wait_for_log(p, "tracker ready", 90)
        return p

    def start_camera(self, dataset=None, loop=False):
        src = f"replay:{dataset or self.dataset}"
        args = ["camera", "--config", str(self.config), "--source", src, "--speed", str(SPEED)]
        if loop:
            args.append("--loop")
        return self.spawn(args, f"camera{len(self.procs)}")

    def cleanup(self):
        for p in self.procs:
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
        for p in self.procs:
            try:
                p.wait(timeout=3)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
        for d in ["/dev/shm", "/tmp/iceoryx2/nodes", "/tmp/iceoryx2/services"]:
            for f in pathlib.Path(d).glob(f"{self.prefix}*") if pathlib.Path(d).exists() else []:
                try:
                    f.unlink()
                except OSError:
                    pass


def wait_for_log(proc, needle, timeout_s):
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if needle in proc.log_path.read_text():
            return
        if proc.poll() is not None:
            raise AssertionError(f"process exited ({proc.returncode}): {proc.log_path.read_text()[-2000:]}")
        time.sleep(0.05)
    raise AssertionError(f"`{needle}` not logged in {timeout_s} s: {proc.log_path.read_text()[-2000:]}")


@pytest.fixture
def rig(star_bin, tmp_path, dataset):
    r = Rig(star_bin, tmp_path, dataset)
    yield r
    r.cleanup()


class Autopilot:
    """The autopilot's side of the link: udpin on the harness's port."""

    def __init__(self, port):
        self.port = port
        self.records = []  # (receive CLOCK_MONOTONIC ns, type, fields dict)
        self.bad_data = 0
        self._stop = threading.Event()
        self._thread = None
        self._conn = None

    def up(self):
        self._conn = mavutil.mavlink_connection(
            f"udpin:127.0.0.1:{self.port}", source_system=1, source_component=1,
            robust_parsing=True, dialect="common")
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()
        return self

    def down(self):
        self._stop.set()
        if self._thread:
            self._thread.join(timeout=2)
        if self._conn:
            self._conn.close()
        self._conn = None

    def _run(self):
        conn = self._conn
        next_hb = next_ts = time.monotonic()
        while not self._stop.is_set():
            now = time.monotonic()
            peer = bool(getattr(conn, "clients", None)) or getattr(conn, "last_address", None) is not None
            if peer and now >= next_hb:
                next_hb = now + 1.0
                conn.mav.heartbeat_send(mavutil.mavlink.MAV_TYPE_QUADROTOR,
                                        mavutil.mavlink.MAV_AUTOPILOT_PX4, 0, 0,
                                        mavutil.mavlink.MAV_STATE_ACTIVE)
            if peer and now >= next_ts:
                next_ts = now + 0.5
                conn.mav.timesync_send(0, time.monotonic_ns())
            try:
                msg = conn.recv_match(blocking=True, timeout=0.02)
            except OSError:
                continue
            if msg is None:
                continue
            t = time.monotonic_ns()
            mtype = msg.get_type()
            if mtype == "BAD_DATA":
                self.bad_data += 1
                continue
            if mtype == "TIMESYNC" and msg.tc1 == 0:
                conn.mav.timesync_send(time.monotonic_ns(), msg.ts1)
            self.records.append((t, mtype, msg.to_dict()))

    def of_type(self, name):
        return [(t, f) for t, m, f in self.records if m == name]


@pytest.fixture
def autopilot(rig):
    ap = Autopilot(rig.port)
    yield ap
    ap.down()


# --- pose conversion, independent of the Rust code ------------------------

def rot_x(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def rot_y(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def rot_z(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def rpy_matrix(roll, pitch, yaw):
    """R = Rz(yaw) Ry(pitch) Rx(roll) (MAVLink / aerospace ZYX)."""
    return rot_z(yaw) @ rot_y(pitch) @ rot_x(roll)


def transform(translation, rotation):
    t = np.eye(4)
    t[:3, :3] = rotation
    t[:3, 3] = translation
    return t


def config_transform(spec):
    r, p, y = np.radians(spec["rpy_deg"])
    return transform(spec["translation_m"], rpy_matrix(r, p, y))


def quat_xyzw_matrix(q):
    x, y, z, w = q / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def tum_matrix(pose7):
    return transform(pose7[:3], quat_xyzw_matrix(np.asarray(pose7[3:7])))


def vpe_world_from_camera(fields):
    """VISION_POSITION_ESTIMATE (ned_from_body) -> world_from_camera."""
    ned_from_body = transform([fields["x"], fields["y"], fields["z"]],
                              rpy_matrix(fields["roll"], fields["pitch"], fields["yaw"]))
    return (np.linalg.inv(config_transform(NED_FROM_WORLD)) @ ned_from_body
            @ config_transform(BODY_FROM_CAMERA))


def pose_error(a, b):
    """(translation m, rotation deg) between two 4x4 poses."""
    d = np.linalg.inv(a) @ b
    cos = np.clip((np.trace(d[:3, :3]) - 1) / 2, -1, 1)
    return np.linalg.norm(a[:3, 3] - b[:3, 3]), np.degrees(np.arccos(cos))
