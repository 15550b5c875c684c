"""Closed-loop flight on vision in ArduPilot SITL (issue 20): the vehicle
flies on what star sees.

One flight: ArduCopter SITL with GPS off and EKF3 on external navigation
only (`extnav.parm`); `star camera --source sim:...` renders the vehicle's
camera at SITL's true pose (SIM_STATE on SERIAL2) from the truth mesh of a
`star synth --preset realistic` room; `star track` tracks it against the
room's map and sends VISION_POSITION_ESTIMATE to SITL's SERIAL1 through a
`sitl.Tap`; the test is the ground station on SERIAL0: it sets the EKF
origin, arms in GUIDED, takes off to ALT_M, flies a SQUARE_M square at
SPEED_MPS (a moving position-and-velocity target at 10 Hz) and lands.

`fly()` returns the record (truth, EKF, star, timing, CPU); `figures()`
reduces it; `plot()` draws the flown square top-down. Used by
`test_sitl_flight.py` (assertions) and `scripts/demo.sh --sitl` (this file
as a script: `python hil_tests/flight.py OUT_DIR [--plot PNG]`).

Geometry. The room is 8 x 6 x 3 m, world z up. The vehicle starts at
world (START_XY_M, its body origin FLOOR_TO_BODY_M above the floor: where
SITL's vehicle rests) facing world +x (SITL home heading 0 = north), so
NED north = world +x, east = world -y, down = world -z. The camera looks
forward, 10 cm ahead of and 5 cm above the body origin. The camera is
CAMERA_WH at the preset's field of view (fx = 210 for 320 px) with the
preset's distortion: a 2-core machine cannot render, track and run SITL at
640 x 512 and 50 Hz at once.
"""

import argparse
import json
import math
import os
import pathlib
import subprocess
import sys
import time

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))

from conftest import STAR, Rig, config_transform, quat_xyzw_matrix, read_tum, tum_matrix, wait_for_log  # noqa: E402
from sitl import Gcs, Sitl, Tap, free_instance, stop_all  # noqa: E402
from pymavlink import mavutil  # noqa: E402

SEED = 1
SQUARE_M = 2.0
SPEED_MPS = 0.5
# Acceleration of the commanded target at the corners (it stops at each).
ACCEL_MPS2 = 0.5
ALT_M = 1.0
# Laps of the square (STAR_FLIGHT_LAPS, default 1: about 35 s armed; 5 laps
# make the 2-minute flight of issue 20's dropped-samples target).
LAPS = int(os.environ.get("STAR_FLIGHT_LAPS", "1"))
CAMERA_WH = (320, 256)
# The sim camera's rate (STAR_SIM_FPS, default 50 = EKF3's cap).
FPS = float(os.environ.get("STAR_SIM_FPS", "50"))
# Extra `[mavlink]` keys for star, ';'-separated (STAR_FLIGHT_MAVLINK). The
# default is the integration guide's ArduPilot setting: poses at least 25 ms
# apart, every other frame of the 50 Hz camera. At 20 ms (every frame) EKF3
# drops about one sample in 400: SITL reads its UART in 2.5 ms loop steps, and
# a pose read one step early gets a jitter-corrected time under 20 ms after
# the one before (docs/benchmarks.md, "Vision samples EKF3 drops").
MAVLINK_EXTRA = os.environ.get("STAR_FLIGHT_MAVLINK", "autopilot_min_interval_ms = 25")
# Extra `[keyframe]` keys for star, ';'-separated (STAR_FLIGHT_KEYFRAME), e.g.
# "hold_for_next_frame = true".
KEYFRAME_EXTRA = os.environ.get("STAR_FLIGHT_KEYFRAME", "")
START_XY_M = (2.5, 4.0)
# SITL's vehicle rests with its body origin this far above home altitude;
# the room's floor is put there.
FLOOR_TO_BODY_M = 0.09
NED_FROM_WORLD = {
    "translation_m": [-START_XY_M[0], START_XY_M[1], FLOOR_TO_BODY_M],
    "rpy_deg": [180.0, 0.0, 0.0],
}
BODY_FROM_CAMERA = {"translation_m": [0.1, 0.0, -0.05], "rpy_deg": [90.0, 0.0, 90.0]}
# ArduPilot's LOCATION_SCALING_FACTOR: meters per 1e-7 degree of latitude.
M_PER_DEG_E7 = 0.011131884502145034
# The keyframe renderer, and the tracker's pixel sizes scaled to the half-size camera.
CONFIG_EXTRA = f"""[render]
renderer = "cpu"
[camera]
fps = {FPS}
""" + (f"[keyframe]\n{KEYFRAME_EXTRA.replace(';', chr(10))}\n" if KEYFRAME_EXTRA else "")
CONFIG_TRACKER = """pyramid_levels = 3
block_size_px = 16
"""
# VISO_DELAY_MS set in SITL: the capture -> SITL delay measured here (min
# about 4 ms, median about 6 ms; docs/benchmarks.md).
VISO_DELAY_MS = 5
# SERIAL1_BAUD for SITL (STAR_SITL_SERIAL1_BAUD, ArduPilot's code: 921 =
# 921 600, 57 = 57 600, its default). SERIAL1 is TCP here, but ArduPilot
# still dates each packet by the byte time at this baud of the packet and of
# what is queued behind it (`receive_time_constraint_us`): at 57 600, 174 µs
# a byte, a HEARTBEAT read in one go with the pose before it dates that pose
# 3.6 ms early, and EKF3's jitter correction then drops it. 50 Hz of vision
# needs about 64 kbit/s, more than 57 600 baud carries: the integration guide
# says 921 600, and so does the flight.
SERIAL1_BAUD = int(os.environ.get("STAR_SITL_SERIAL1_BAUD", "921"))
COPTER_GUIDED = 4
COPTER_LAND = 9
CLK_TCK = os.sysconf("SC_CLK_TCK")


def log(text):
    print(text, flush=True)


# --- truth: SIM_STATE in the local NED frame of the origin -------------------

def ned_of(origin, lat_e7, lon_e7, alt_m):
    """SIM_STATE position -> local NED (m), ArduPilot's flat earth (as
    `synth::sim_camera::truth::ned_offset_m`)."""
    lat0, lon0, alt0 = origin
    north = (lat_e7 - lat0) * M_PER_DEG_E7
    scale = max(math.cos(math.radians(0.5 * (lat_e7 + lat0) * 1e-7)), 0.01)
    east = (lon_e7 - lon0) * M_PER_DEG_E7 * scale
    return np.array([north, east, alt0 - alt_m])


def truth_track(states, origin):
    """[(t, SIM_STATE)] -> times (N,), NED positions (N, 3)."""
    t = np.array([s[0] for s in states])
    p = np.array([ned_of(origin, m.lat_int, m.lon_int, m.alt) for _, m in states])
    return t, p


def interp(t_query, t, values):
    return np.stack([np.interp(t_query, t, values[:, k]) for k in range(values.shape[1])], axis=1)


def world_from_camera_at_rest(q_wxyz):
    """The camera pose of the vehicle at the origin with attitude q: star's start hint."""
    w, x, y, z = q_wxyz
    ned_from_body = np.eye(4)
    ned_from_body[:3, :3] = quat_xyzw_matrix(np.array([x, y, z, w]))
    m = np.linalg.inv(config_transform(NED_FROM_WORLD)) @ ned_from_body @ config_transform(BODY_FROM_CAMERA)
    return [*m[:3, 3], *quat_xyzw_of(m[:3, :3])]


def quat_xyzw_of(r):
    """Rotation matrix -> unit quaternion (x, y, z, w), Shepperd's method."""
    t = np.trace(r)
    if t > max(r[0, 0], r[1, 1], r[2, 2]):
        w = math.sqrt(1 + t) / 2
        q = ((r[2, 1] - r[1, 2]) / (4 * w), (r[0, 2] - r[2, 0]) / (4 * w), (r[1, 0] - r[0, 1]) / (4 * w), w)
    else:
        i = int(np.argmax(np.diag(r)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = math.sqrt(1 + r[i, i] - r[j, j] - r[k, k]) * 2
        q = [0.0, 0.0, 0.0, (r[k, j] - r[j, k]) / s]
        q[i] = s / 4
        q[j] = (r[j, i] + r[i, j]) / s
        q[k] = (r[k, i] + r[i, k]) / s
    return list(q)


def star_ned(trajectory):
    """star's trajectory file (world_from_camera, capture time CLOCK_MONOTONIC
    s) -> capture times (N,), body positions in NED (N, 3): what it sent."""
    stamps, poses = read_tum(trajectory)
    nfw, bfc_inv = config_transform(NED_FROM_WORLD), np.linalg.inv(config_transform(BODY_FROM_CAMERA))
    p = np.array([(nfw @ tum_matrix(pose) @ bfc_inv)[:3, 3] for pose in poses])
    return stamps, p


# --- CPU use from /proc ------------------------------------------------------

def cpu_ticks(pid):
    """utime + stime of a process (and its reaped children), clock ticks."""
    fields = pathlib.Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return sum(int(v) for v in fields[11:15])


class CpuMeter:
    def __init__(self, pids):
        self.pids = pids
        self.start = {name: cpu_ticks(pid) for name, pid in pids.items()}
        self.t0 = time.monotonic()

    def percent(self):
        wall = time.monotonic() - self.t0
        out = {}
        for name, pid in self.pids.items():
            try:
                out[name] = 100.0 * (cpu_ticks(pid) - self.start[name]) / CLK_TCK / wall
            except OSError:
                out[name] = float("nan")
        return out


# --- the ground station's commands --------------------------------------------

def command(gcs, cmd, *params, timeout_s=5.0, ok=(0,)):
    """COMMAND_LONG and its COMMAND_ACK result (None: no answer)."""
    conn = gcs.conn
    since = time.monotonic()
    p = list(params) + [0] * (7 - len(params))
    conn.mav.command_long_send(conn.target_system, conn.target_component, cmd, 0, *p)
    end = since + timeout_s
    while time.monotonic() < end:
        for t, m in gcs.kept["COMMAND_ACK"]:
            if t >= since and m.command == cmd:
                return m.result
        time.sleep(0.02)
    return None


def armed(gcs):
    """The autopilot's own HEARTBEAT says armed (SITL also forwards star's
    and the sim camera's heartbeats, which never do)."""
    beats = [m for _, m in gcs.kept["HEARTBEAT"] if m.autopilot != mavutil.mavlink.MAV_AUTOPILOT_INVALID]
    return bool(beats) and bool(beats[-1].base_mode & mavutil.mavlink.MAV_MODE_FLAG_SAFETY_ARMED)


def ekf_now(gcs):
    return np.array(gcs.positions[-1][1]) if gcs.positions else None


def wait_until(predicate, timeout_s, what, check=None):
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if predicate():
            return time.monotonic()
        if check:
            check()
        time.sleep(0.05)
    raise AssertionError(f"{what}: not within {timeout_s} s")


def send_target(gcs, p_ned, v_ned, yaw_rad):
    """Position, velocity and a fixed heading (without one, GUIDED turns the
    nose into the direction of travel: 90 deg turns at each corner)."""
    conn = gcs.conn
    mask = 64 | 128 | 256 | 2048  # position, velocity, yaw; no acceleration, yaw rate
    conn.mav.set_position_target_local_ned_send(
        0, conn.target_system, conn.target_component, mavutil.mavlink.MAV_FRAME_LOCAL_NED, mask,
        *p_ned, *v_ned, 0, 0, 0, yaw_rad, 0)


def side_progress_m(t_s):
    """Distance along one side after `t_s`: accelerate at ACCEL_MPS2 to
    SPEED_MPS, cruise, brake to a stop at the corner; and the speed."""
    t_ramp = SPEED_MPS / ACCEL_MPS2
    d_ramp = 0.5 * ACCEL_MPS2 * t_ramp ** 2
    t_cruise = (SQUARE_M - 2 * d_ramp) / SPEED_MPS
    if t_s <= 0:
        return 0.0, 0.0
    if t_s < t_ramp:
        return 0.5 * ACCEL_MPS2 * t_s ** 2, ACCEL_MPS2 * t_s
    if t_s < t_ramp + t_cruise:
        return d_ramp + SPEED_MPS * (t_s - t_ramp), SPEED_MPS
    t_brake = min(t_s - t_ramp - t_cruise, t_ramp)
    return (d_ramp + SPEED_MPS * t_cruise + SPEED_MPS * t_brake - 0.5 * ACCEL_MPS2 * t_brake ** 2,
            SPEED_MPS - ACCEL_MPS2 * t_brake)


def side_s():
    """Seconds per side."""
    return 2 * SPEED_MPS / ACCEL_MPS2 + (SQUARE_M - SPEED_MPS ** 2 / ACCEL_MPS2) / SPEED_MPS


def square_target(t_s, z_m, laps=1):
    """Position and velocity `t_s` into `laps` laps of the square (north,
    east, south, west from the origin, stopping at each corner), at height
    `-z_m`."""
    corners = np.array([(0, 0), (SQUARE_M, 0), (SQUARE_M, SQUARE_M), (0, SQUARE_M), (0, 0)], float)
    if t_s >= 4 * laps * side_s():
        return (0.0, 0.0, z_m), (0.0, 0.0, 0.0)
    t_s = t_s % (4 * side_s())
    k = min(int(t_s // side_s()), 3)
    d, v = side_progress_m(t_s - k * side_s())
    u = (corners[k + 1] - corners[k]) / SQUARE_M
    p = corners[k] + u * d
    return (p[0], p[1], z_m), (u[0] * v, u[1] * v, 0.0)


# --- the flight ----------------------------------------------------------------

def synth_scene(star_bin, out):
    """The room (`star synth`, one frame: the sim camera renders the rest)."""
    if not (out / "synth.toml").exists():
        subprocess.run([str(star_bin), "--log", "warn", "synth", "--preset", "realistic", str(out),
                        "--frames", "1", "--seed", str(SEED), "--no-depth"], check=True, timeout=300)
    return out


def camera_lines(scene):
    """The sim scene's camera at CAMERA_WH: the preset's field of view and distortion."""
    lines = (scene / "camera.toml").read_text().splitlines()
    full = {k.strip(): float(v) for k, v in (line.split("=") for line in lines
                                              if "=" in line and not line.startswith("["))}
    s = CAMERA_WH[0] / full["width"]
    out = [f"width = {CAMERA_WH[0]}", f"height = {CAMERA_WH[1]}", f"fx = {full['fx'] * s}", f"fy = {full['fy'] * s}",
           f"cx = {(full['cx'] + 0.5) * s - 0.5}", f"cy = {(full['cy'] + 0.5) * s - 0.5}"]
    dist = lines[lines.index("[distortion]") + 1:] if "[distortion]" in lines else []
    return out + ["[camera.intrinsics.distortion]"] + [d for d in dist if "=" in d]


def set_param(gcs, name, value, timeout_s=5.0):
    """PARAM_SET, confirmed by the PARAM_VALUE SITL answers with."""
    conn = gcs.conn
    since = time.monotonic()
    conn.mav.param_set_send(conn.target_system, conn.target_component, name.encode(), float(value),
                            mavutil.mavlink.MAV_PARAM_TYPE_REAL32)
    wait_until(lambda: any(t >= since and m.param_id == name and abs(m.param_value - value) < 1e-3
                           for t, m in gcs.kept["PARAM_VALUE"]), timeout_s, f"{name} = {value}")


def fly(star_bin, work, scene, viso_delay_ms=VISO_DELAY_MS):
    """One closed-loop flight; returns its record (see `figures`).
    `viso_delay_ms`: VISO_DELAY_MS for SITL (None: extnav.parm's 10)."""
    work.mkdir(parents=True, exist_ok=True)
    sitl = Sitl(free_instance(), work / "sitl", params={"SERIAL1_BAUD": SERIAL1_BAUD})
    gcs = tap = None
    rig = Rig(star_bin, work, scene)
    record = {"phases": {}}
    try:
        gcs = Gcs(sitl.gcs_port, keep=("SIM_STATE", "HEARTBEAT", "COMMAND_ACK", "GPS_GLOBAL_ORIGIN",
                                           "PARAM_VALUE"))
        gcs.start_streams()
        conn = gcs.conn
        conn.mav.command_long_send(conn.target_system, conn.target_component,
                                   mavutil.mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0, 108, 20_000, 0, 0, 0, 0, 0)
        gcs.wait_text("EKF3 IMU0 tilt alignment complete", 60)
        if viso_delay_ms is not None:
            set_param(gcs, "VISO_DELAY_MS", viso_delay_ms)
        record["viso_delay_ms"] = viso_delay_ms
        record["serial1_baud"] = SERIAL1_BAUD
        wait_until(lambda: gcs.kept["SIM_STATE"], 10, "SIM_STATE on the GCS link")
        rest = gcs.kept["SIM_STATE"][-1][1]
        origin = (rest.lat_int, rest.lon_int, rest.alt)
        record["origin"] = origin
        tap = Tap(sitl.serial1_port)
        hint = world_from_camera_at_rest((rest.q1, rest.q2, rest.q3, rest.q4))
        yaw_rad = rest.yaw
        rig.write_config(extra=CONFIG_EXTRA, tracker=CONFIG_TRACKER, camera_lines=camera_lines(scene), init_pose=hint,
                         ned_from_world=NED_FROM_WORLD, body_from_camera=BODY_FROM_CAMERA)
        if MAVLINK_EXTRA:
            rig.config.write_text(rig.config.read_text().replace(
                "[mavlink]\n", "[mavlink]\n" + MAVLINK_EXTRA.replace(";", "\n") + "\n", 1))
        trajectory = work / "star.txt"
        track = rig.spawn(["track", "--config", str(rig.config), "--mavlink", f"tcpout:127.0.0.1:{tap.port}",
                           "--trajectory", str(trajectory)], "track")
        wait_for_log(track, "tracker ready", 120)
        lat, lon, alt = rest.lat_int * 1e-7, rest.lon_int * 1e-7, rest.alt
        source = (f"sim:tcpout:127.0.0.1:{sitl.serial1_port + 1}?scene={scene}"
                  f"&origin={lat:.7f},{lon:.7f},{alt:.4f}")
        # STAR_SIM_TRACE=1: the sim camera logs every frame's pose (trace).
        camera = rig.spawn(["camera", "--config", str(rig.config), "--source", source], "camera",
                           "info,star::synth::sim_camera=trace" if os.environ.get("STAR_SIM_TRACE") else "info")
        procs = {"sitl": sitl.proc, "camera": camera, "track": track}

        def alive():
            for name, p in procs.items():
                assert p.poll() is None, f"{name} exited ({p.returncode}): " + (
                    p.log_path.read_text()[-3000:] if hasattr(p, "log_path") else "")

        t_fused = gcs.wait_text("EKF3 IMU0 is using external nav data", 120)
        record["phases"]["fused"] = t_fused
        log("EKF3 fuses star's vision")
        # The EKF origin once the EKF is on vision, the vehicle at rest at
        # the origin: EKF3 shifts its reported height by its height at the
        # moment the origin is set (on the barometer before vision: a few cm).
        time.sleep(2.0)
        conn.mav.set_gps_global_origin_send(conn.target_system, rest.lat_int, rest.lon_int,
                                            int(round(rest.alt * 1000)), 0)
        wait_until(lambda: gcs.kept["GPS_GLOBAL_ORIGIN"], 10, "GPS_GLOBAL_ORIGIN from SITL", alive)
        cpu = CpuMeter({"sitl": sitl.proc.pid, "star camera": camera.pid, "star track": track.pid,
                        "harness (python)": os.getpid()})
        # GUIDED, then arm (retried while the pre-arm checks settle).
        wait_until(lambda: command(gcs, mavutil.mavlink.MAV_CMD_DO_SET_MODE, 1, COPTER_GUIDED) == 0,
                   30, "GUIDED mode", alive)

        def try_arm():
            return command(gcs, mavutil.mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1) == 0 or armed(gcs)
        try:
            t_armed = wait_until(try_arm, 60, "arming", alive)
        except AssertionError as e:
            raise AssertionError(f"{e}; pre-arm: {[x for _, x in gcs.texts if 'PreArm' in x][-5:]}") from None
        record["phases"]["armed"] = t_armed
        log("armed in GUIDED; taking off")
        assert command(gcs, mavutil.mavlink.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, ALT_M) == 0, "takeoff refused"
        wait_until(lambda: ekf_now(gcs)[2] < -0.95 * ALT_M, 30, f"climb to {ALT_M} m", alive)
        time.sleep(2.0)
        record["phases"]["square"] = t0 = time.monotonic()
        log(f"square: {LAPS} x {4 * side_s():.0f} s")
        while True:
            t = time.monotonic() - t0
            p, v = square_target(t, -ALT_M, LAPS)
            send_target(gcs, p, v, yaw_rad)
            if t >= 4 * LAPS * side_s() + 3.0:  # and 3 s of hover at the end
                break
            alive()
            time.sleep(0.1)
        record["phases"]["land"] = time.monotonic()
        assert command(gcs, mavutil.mavlink.MAV_CMD_DO_SET_MODE, 1, COPTER_LAND) == 0, "LAND refused"
        t_landed = wait_until(lambda: not armed(gcs), 40, "landing and disarming", alive)
        record["phases"]["disarmed"] = t_landed
        record["cpu_percent"] = cpu.percent()
        time.sleep(0.3)
    finally:
        stop_all(sitl, rig, tap, gcs)
    record["truth"] = [(t, (m.lat_int, m.lon_int, m.alt)) for t, m in gcs.kept["SIM_STATE"]]
    record["ekf"] = list(gcs.positions)
    record["vpe"] = [(t, f) for t, f in tap.of_type("VISION_POSITION_ESTIMATE")]
    record["star_trajectory"] = str(trajectory)
    record["texts"] = [x for _, x in gcs.texts]
    record["camera_log"] = str(camera.log_path)
    record["track_log"] = str(track.log_path)
    record["visp"] = sitl.vision_log()
    (work / "record.json").write_text(json.dumps(record))
    return record


# --- figures ----------------------------------------------------------------------

def errors_cm(t, p, t_truth, p_truth):
    d = np.linalg.norm(p - interp(t, t_truth, p_truth), axis=1) * 100
    return float(np.sqrt(np.mean(d ** 2))), float(np.max(d))


def figures(record):
    """The flight's figures: EKF vs truth and star vs truth (RMS, max, cm)
    from arming to disarming; capture-to-SITL delay; CPU."""
    origin = record["origin"]
    t_truth = np.array([t for t, _ in record["truth"]])
    p_truth = np.array([ned_of(origin, *v) for _, v in record["truth"]])
    t_arm, t_disarm = record["phases"]["armed"], record["phases"]["disarmed"]
    ekf = [(t, p) for t, p in record["ekf"] if t_arm <= t <= t_disarm]
    t_ekf = np.array([t for t, _ in ekf])
    p_ekf = np.array([p for _, p in ekf])
    # star: capture time (CLOCK_MONOTONIC) and position; the truth there.
    t_star, p_star = star_ned(record["star_trajectory"])
    in_flight = (t_star >= t_arm) & (t_star <= t_disarm)
    out = {"ekf_samples": len(ekf), "star_poses": int(in_flight.sum())}
    out["ekf_rms_cm"], out["ekf_max_cm"] = errors_cm(t_ekf, p_ekf, t_truth, p_truth)
    out["ekf_mean_cm"] = [float(v) for v in (p_ekf - interp(t_ekf, t_truth, p_truth)).mean(axis=0) * 100]
    # The time shift that best aligns the EKF with the truth (constant
    # offset removed): positive, the EKF lags; negative, it leads.
    def shifted_rms(shift_s):
        d = p_ekf - interp(t_ekf - shift_s, t_truth, p_truth)
        d -= d.mean(axis=0)
        return float(np.sqrt(np.mean(np.sum(d ** 2, axis=1))))
    shifts = np.arange(-0.1, 0.1001, 0.005)
    out["ekf_lag_ms"] = float(shifts[int(np.argmin([shifted_rms(s) for s in shifts]))] * 1e3)
    out["star_rms_cm"], out["star_max_cm"] = errors_cm(t_star[in_flight], p_star[in_flight], t_truth, p_truth)
    # Capture -> SITL: each VISION_POSITION_ESTIMATE through the tap, matched
    # to star's trajectory row of the same position (same pose, same frame).
    delays = []
    j = 0
    for t_arrive, f in record["vpe"]:
        p = np.array([f["x"], f["y"], f["z"]])
        k = j
        while k < len(t_star) and t_star[k] <= t_arrive and np.linalg.norm(p_star[k] - p) > 1e-4:
            k += 1
        if k < len(t_star) and t_star[k] <= t_arrive:
            delays.append((t_arrive - t_star[k]) * 1e3)
            j = k + 1
    d = np.array(delays)
    out["delay_matched"] = len(d)
    if len(d):
        out["delay_ms"] = {k: float(np.percentile(d, q)) for k, q in
                           (("min", 0), ("p5", 5), ("median", 50), ("p95", 95), ("max", 100))}
        # ArduPilot's jitter correction dates a sample by the smallest lag of
        # the last 100 (`JitterCorrection`): VISO_DELAY_MS should be that lag.
        windows = [d[i:i + 100].min() for i in range(0, max(1, len(d) - 99), 100)]
        out["viso_delay_ms"] = float(np.median(windows))
    # EKF3's own log: vision samples it received, and those its 20 ms rule
    # dropped (replayed on its corrected times, see `ekf3_dropped`).
    visp = record.get("visp") or []
    out["visp"] = len(visp)
    out.update(ekf3_dropped(visp))
    # The same, armed to disarmed only (VISP rows timed by their arrival at
    # the tap, found by `usec`).
    arrival = {int(f["usec"]): t for t, f in record["vpe"]}
    armed_rows = [row for row in visp if t_arm <= arrival.get(int(row[1]), -1.0) <= t_disarm]
    out["visp_armed"] = len(armed_rows)
    out["visp_dropped_armed"] = ekf3_dropped(armed_rows)["visp_dropped"]
    out["cpu_percent"] = record["cpu_percent"]
    out["flight_s"] = t_disarm - t_arm
    return out


# EKF3's minimum spacing of external navigation samples
# (NavEKF3::extNavIntervalMin_ms).
EXTNAV_INTERVAL_MIN_MS = 20


def ekf3_dropped(visp):
    """Replays the rule by which EKF3 drops vision samples on SITL's VISP log
    rows (TimeUS, RTimeUS, CTimeMS, Ign): `NavEKF3_core::writeExtNavData`
    returns early when `timeStamp_ms - extNavMeasTime_ms < 20` (uint32 ms),
    where `timeStamp_ms` is CTimeMS (the sample's `usec` through ArduPilot's
    jitter correction, truncated to ms) and `extNavMeasTime_ms` is the
    CTimeMS of the last sample it *kept*. Rows with Ign set were not passed to
    the EKF (AP_VisualOdom ignores samples around a reset) and are skipped.

    Returns the number dropped and how many of those star itself sent closer
    than 20 ms to the last kept one (its `usec`, RTimeUS); the others were
    moved closer by ArduPilot's jitter correction."""
    kept_c = kept_r = None
    dropped = by_star = ignored = 0
    for _, r_us, c_ms, ign in visp:
        if ign:
            ignored += 1
            continue
        if kept_c is not None and (int(c_ms) - kept_c) % (1 << 32) < EXTNAV_INTERVAL_MIN_MS:
            dropped += 1
            by_star += (r_us - kept_r) < EXTNAV_INTERVAL_MIN_MS * 1000
            continue
        kept_c, kept_r = int(c_ms), r_us
    return {"visp_dropped": dropped, "visp_dropped_star_usec": by_star, "visp_ignored": ignored}


def report(f):
    lines = [
        f"EKF (LOCAL_POSITION_NED) vs SITL truth: RMS {f['ekf_rms_cm']:.2f} cm, max {f['ekf_max_cm']:.2f} cm "
        f"({f['ekf_samples']} samples, {f['flight_s']:.1f} s armed); mean north/east/down "
        + "/".join(f"{v:.2f}" for v in f["ekf_mean_cm"]) + f" cm; best time alignment {f['ekf_lag_ms']:+.0f} ms "
        "(negative: EKF leads)",
        f"star (sent pose) vs SITL truth at capture: RMS {f['star_rms_cm']:.2f} cm, max {f['star_max_cm']:.2f} cm "
        f"({f['star_poses']} poses)",
    ]
    if "delay_ms" in f:
        d = f["delay_ms"]
        lines.append(f"capture -> SITL (SERIAL1) delay: min {d['min']:.1f}, median {d['median']:.1f}, "
                     f"p95 {d['p95']:.1f}, max {d['max']:.1f} ms over {f['delay_matched']} poses; "
                     f"VISO_DELAY_MS to set: {f['viso_delay_ms']:.0f}")
    lines.append(f"EKF3 log: {f['visp']} vision samples, {f['visp_dropped']} dropped by its 20 ms rule "
                 f"({f['visp_dropped_star_usec']} of them sent by star under 20 ms apart, the rest moved closer "
                 f"by ArduPilot's jitter correction; {f['visp_ignored']} ignored by AP_VisualOdom); armed: "
                 f"{f['visp_dropped_armed']} of {f['visp_armed']}")
    lines.append("CPU (% of one core, armed to disarmed): " +
                 ", ".join(f"{k} {v:.0f} %" for k, v in f["cpu_percent"].items()))
    return "\n".join(lines)


def plot(record, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    origin = record["origin"]
    t_arm, t_disarm = record["phases"]["armed"], record["phases"]["disarmed"]
    truth = np.array([ned_of(origin, *v) for t, v in record["truth"] if t_arm <= t <= t_disarm])
    ekf = np.array([p for t, p in record["ekf"] if t_arm <= t <= t_disarm])
    t_star, p_star = star_ned(record["star_trajectory"])
    star = p_star[(t_star >= t_arm) & (t_star <= t_disarm)]
    fig, ax = plt.subplots(figsize=(5, 5), dpi=100)
    square = np.array([(0, 0), (SQUARE_M, 0), (SQUARE_M, SQUARE_M), (0, SQUARE_M), (0, 0)])
    ax.plot(square[:, 1], square[:, 0], color="0.8", lw=6, label="commanded square", zorder=1)
    ax.plot(truth[:, 1], truth[:, 0], "k-", lw=1.5, label="SITL truth", zorder=2)
    ax.plot(ekf[:, 1], ekf[:, 0], "C0--", lw=1.2, label="EKF3 (LOCAL_POSITION_NED)", zorder=3)
    ax.plot(star[:, 1], star[:, 0], "C3.", ms=1.5, label="star (sent)", zorder=4)
    ax.set_xlabel("east, m")
    ax.set_ylabel("north, m")
    ax.set_aspect("equal")
    ax.grid(True, lw=0.3)
    f = figures(record)
    ax.set_title(f"Closed loop on vision, ArduCopter SITL\nEKF vs truth RMS {f['ekf_rms_cm']:.1f} cm, "
                 f"max {f['ekf_max_cm']:.1f} cm", fontsize=9)
    ax.legend(loc="center", fontsize=7)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("out", type=pathlib.Path, help="working folder (SITL, logs, the scene)")
    parser.add_argument("--plot", type=pathlib.Path, help="write the top-down plot here (PNG)")
    parser.add_argument("--viso-delay-ms", type=float, default=VISO_DELAY_MS,
                        help=f"VISO_DELAY_MS for SITL (default {VISO_DELAY_MS})")
    parser.add_argument("--replot", action="store_true",
                        help="no flight: figures and plot from OUT/flight/record.json")
    args = parser.parse_args()
    if args.replot:
        record = json.loads((args.out / "flight" / "record.json").read_text())
    else:
        star_bin = STAR
        scene = synth_scene(star_bin, args.out / "scene")
        record = fly(star_bin, args.out / "flight", scene, args.viso_delay_ms)
    print(report(figures(record)))
    if args.plot:
        plot(record, args.plot)
        print(f"plot: {args.plot}")


if __name__ == "__main__":
    main()
