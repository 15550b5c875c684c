"""A real autopilot in the loop (issue 20): ArduPilot's ArduCopter SITL with
EKF3 fed only by star's poses on SERIAL1.

Each start is a fresh SITL (its own temporary directory and ports) and a fresh
`star run` replaying a still camera (frame 0 of the session's dataset,
repeated): the SITL boots, the test connects as the GCS on SERIAL0 (5760 +
10 N), waits for EKF3's tilt alignment, then starts
star with `--mavlink tcpout:` to a transparent TCP tap in front of SITL's
SERIAL1 (5762 + 10 N). The EKF origin is not set (nothing arms). The tap forwards every byte both ways unchanged and
decodes a copy of what star sends, so the test knows when star's first pose
went out and what it said.

Checked for each start:
- EKF3 announces "EKF3 IMU0 is using external nav data" (STATUSTEXT on the
  GCS link) within 1 s of star's first pose;
- no fallback afterwards ("stopped aiding"; the EKF height staying on the
  vision height: a fallback to baro moves it, issue 20 saw -1.36 m -> +0.52 m);
- the EKF's LOCAL_POSITION_NED matches star's last pose within 1 cm, and its
  yaw (ATTITUDE) star's yaw within YAW_TOL_DEG;
- from SITL's own log (VISP, when pymavlink can read it): how old EKF3 dated
  the samples and how many came under 20 ms apart in its corrected time.

`STAR_SITL_STARTS` starts (default 5; the issue's 20 with
`STAR_SITL_STARTS=20`); the figures are printed (`pytest -s`). One more start
sends ODOMETRY (`mavlink.message = "odometry"`) and checks it is fused too.

The SITL binary is `$STAR_SITL_DIR/arducopter` (default `../shared/sitl`
beside the repository, see its README); without it these tests skip.
"""

import math
import os
import time
from concurrent.futures import ThreadPoolExecutor

import pytest

from conftest import Rig, write_subset
from sitl import SKIP, Gcs, Sitl, Tap, angle_deg, free_instance, stop_all, yaw_of

STARTS = int(os.environ.get("STAR_SITL_STARTS", "5"))
# Frames of the still sequence star replays (50 Hz): 6 s of poses.
STILL_FRAMES = 300
FUSE_WITHIN_S = 1.0
POSITION_TOL_M = 0.01
YAW_TOL_DEG = 1.0
# How old EKF3 may date samples. Issue 20's defect (the clock switched
# under the first poses) had EKF3's jitter correction date them at its
# 500 ms limit. The median is the dating itself: VISO_DELAY_MS 10 + the
# transport through the tap; on this VM, idle, 28-33 ms for
# VISION_POSITION_ESTIMATE and 74 ms for ODOMETRY (likely its longer message at
# SERIAL1's default 57 600 baud, not checked; 64 ms in stop 47's CI run). The max allows
# a scheduling stall of the shared CI machine (176 ms in that run) but not
# the 500 ms limit.
MEDIAN_LAG_MS = 150.0
MAX_LAG_MS = 400.0
# Samples older than this are counted and printed (not a failure alone).
SLOW_LAG_MS = 150.0

pytestmark = SKIP


@pytest.fixture(scope="module")
def still(dataset, tmp_path_factory):
    """Frame 0 of the session's sequence, STILL_FRAMES times: a camera that
    does not move, so the EKF's estimate must settle on star's pose."""
    return write_subset(dataset, tmp_path_factory.mktemp("still") / "still", [0] * STILL_FRAMES)


def boot(tmp):
    """A fresh SITL in `tmp`, booted to EKF3's tilt alignment, with the GCS
    link on it: (sitl, gcs)."""
    sitl = Sitl(free_instance(), tmp / "sitl")
    gcs = None
    try:
        gcs = Gcs(sitl.gcs_port)
        gcs.start_streams()
        # No SET_GPS_GLOBAL_ORIGIN: nothing arms here, and an origin set now
        # would shift the EKF's reported height by its (baro) height at that
        # moment (a few cm), which is ArduPilot's bookkeeping, not star's.
        gcs.wait_text("EKF3 IMU0 tilt alignment complete", 40)
    except BaseException:
        if gcs is not None:
            gcs.close()
        sitl.stop()
        raise
    return sitl, gcs


def one_start(star_bin, still, tmp, message="vision_position_estimate", booted=None):
    """One `star run` against a fresh SITL (`booted`, from `boot`, or booted
    here); returns the figures of this start."""
    sitl, gcs = booted if booted is not None else boot(tmp)
    tap = None
    rig = Rig(star_bin, tmp, still)
    try:
        if message != "vision_position_estimate":
            rig.config.write_text(rig.config.read_text().replace("[mavlink]\n", f'[mavlink]\nmessage = "{message}"\n', 1))
        tap = Tap(sitl.serial1_port)
        run = rig.spawn(["run", "--config", str(rig.config), "--source", f"replay:{still}",
                         "--mavlink", f"tcpout:127.0.0.1:{tap.port}", "--idle-exit-s", "1"], "run")
        run.communicate(timeout=STILL_FRAMES / 50 + 60)
        assert run.returncode == 0, run.log_path.read_text()[-3000:]
        time.sleep(0.3)
        kind = "VISION_POSITION_ESTIMATE" if message == "vision_position_estimate" else "ODOMETRY"
        poses = tap.of_type(kind)
        assert len(poses) > 0.8 * STILL_FRAMES, f"{len(poses)} {kind} through the tap"
        first_pose = poses[0][0]
        fused = [t for t, text in gcs.texts if "EKF3 IMU0 is using external nav data" in text]
        assert fused, f"EKF3 never used external nav: {[x for _, x in gcs.texts]}"
        fused_after_s = fused[0] - first_pose
        fallbacks = [text for t, text in gcs.texts if t > fused[0] and "stopped aiding" in text]
        # The EKF against star over the last 2 s of poses: position and yaw.
        last_t, last = poses[-1]
        sent = (last["x"], last["y"], last["z"])
        window = [p for t, p in gcs.positions if last_t - 2.0 <= t <= last_t + 0.1]
        assert window, "no LOCAL_POSITION_NED in the last 2 s"
        position_err = max(math.dist(p, sent) for p in window)
        # The height over the whole fused time (a fallback to baro moves it).
        fused_heights = [p[2] for t, p in gcs.positions if t > fused[0] + 1.0 and t <= last_t]
        height_err = max(abs(z - sent[2]) for z in fused_heights) if fused_heights else float("nan")
        yaws = [y for t, y in gcs.attitudes if last_t - 2.0 <= t <= last_t + 0.1]
        yaw_err = max(angle_deg(y, yaw_of(last)) for y in yaws)
        usecs = [f["usec" if "usec" in f else "time_usec"] for _, f in poses]
        run_log = run.log_path.read_text()
        figures = {
            "message": kind,
            "poses": len(poses),
            "fused_after_s": fused_after_s,
            "fallbacks": fallbacks,
            "position_err_m": position_err,
            "height_err_m": height_err,
            "yaw_err_deg": yaw_err,
            "usec_increasing": all(b > a for a, b in zip(usecs, usecs[1:])),
            "min_usec_gap_ms": min(b - a for a, b in zip(usecs, usecs[1:])) / 1e3,
            "usec_under_20ms": sum(1 for a, b in zip(usecs, usecs[1:]) if b - a < 20_000),
            "own_clock": "no TIMESYNC answer" in run_log,
            "texts": [x for _, x in gcs.texts],
        }
    finally:
        stop_all(sitl, rig, tap, gcs)
    visp = sitl.vision_log()
    if visp:
        # How old EKF3 dated each sample (its time at logging minus the
        # corrected sample time), and samples under 20 ms apart in corrected
        # time (EKF3 drops those); of the latter, how many had star's usec
        # under 20 ms apart too (the rest come from ArduPilot's own jitter
        # correction converging on the transport lag).
        lags = [t_us / 1000 - c_ms for t_us, _, c_ms, _ in visp]
        pairs = list(zip(visp, visp[1:]))
        under = [(a, b) for a, b in pairs if b[2] - a[2] < 20]
        figures.update({
            "visp": len(visp),
            "visp_max_lag_ms": max(lags),
            "visp_median_lag_ms": sorted(lags)[len(lags) // 2],
            "visp_over_150ms": sum(1 for x in lags if x > SLOW_LAG_MS),
            "visp_under_20ms": len(under),
            "visp_under_20ms_by_usec": sum(1 for a, b in under if b[1] - a[1] < 20_000),
        })
    return figures


def report(figures):
    keys = ["fused_after_s", "position_err_m", "height_err_m", "yaw_err_deg", "min_usec_gap_ms", "usec_under_20ms",
            "poses",
            "visp", "visp_max_lag_ms", "visp_median_lag_ms", "visp_over_150ms", "visp_under_20ms", "visp_under_20ms_by_usec",
            "own_clock"]
    return "  ".join(f"{k}={figures[k]:.3f}" if isinstance(figures.get(k), float) else f"{k}={figures.get(k)}"
                     for k in keys)


def problems(figures):
    """What is wrong with a start, as messages (empty: a good start)."""
    if "error" in figures:
        return [figures["error"]]
    found = []
    if figures["own_clock"]:
        found.append("star fell back to its own clock although SITL answers TIMESYNC")
    if not figures["usec_increasing"]:
        found.append(f"usec not increasing (smallest step {figures['min_usec_gap_ms']:.1f} ms)")
    if figures["fused_after_s"] > FUSE_WITHIN_S:
        found.append(f"fused {figures['fused_after_s']:.2f} s after the first pose")
    if figures["fallbacks"]:
        found.append(f"fallback: {figures['fallbacks']}")
    if not figures["position_err_m"] <= POSITION_TOL_M:
        found.append(f"EKF position {figures['position_err_m'] * 100:.2f} cm from star")
    if not figures["height_err_m"] <= POSITION_TOL_M:
        found.append(f"EKF height {figures['height_err_m'] * 100:.2f} cm from star after fusing")
    if not figures["yaw_err_deg"] <= YAW_TOL_DEG:
        found.append(f"EKF yaw {figures['yaw_err_deg']:.2f} deg from star")
    # Issue 20's first defect made EKF3 date samples 500 ms old.
    if figures.get("visp_median_lag_ms", 0) > MEDIAN_LAG_MS:
        found.append(f"EKF3 dated the samples {figures['visp_median_lag_ms']:.0f} ms old (median)")
    if figures.get("visp_max_lag_ms", 0) > MAX_LAG_MS:
        found.append(f"EKF3 dated a sample {figures['visp_max_lag_ms']:.0f} ms old")
    return found


def test_vision_position_estimate_fused_from_the_first_second(star_bin, still, tmp_path):
    results = []
    dirs = [tmp_path / f"start{k}" for k in range(STARTS)]
    for tmp in dirs:
        tmp.mkdir()
    # Each start's SITL boots (5-6 s to EKF3's tilt alignment) while the
    # start before it runs, as an autopilot is up before its companion
    # computer: every start still gets a fresh SITL and a fresh star.
    with ThreadPoolExecutor(max_workers=1) as pool:
        pending = pool.submit(boot, dirs[0])
        try:
            for k in range(STARTS):
                booting, pending = pending, None
                if k + 1 < STARTS:
                    pending = pool.submit(boot, dirs[k + 1])
                try:
                    figures = one_start(star_bin, still, dirs[k], booted=booting.result())
                except AssertionError as e:
                    figures = {"error": str(e)}
                print(f"\nstart {k + 1}/{STARTS}: " + (report(figures) if "error" not in figures else figures["error"]))
                for p in problems(figures):
                    print(f"  problem: {p}")
                results.append(figures)
        finally:
            # A start that raised leaves the next SITL booting: stop it.
            if pending is not None:
                try:
                    sitl, gcs = pending.result()
                    gcs.close()
                    sitl.stop()
                except BaseException:  # noqa: BLE001 - its own failure is not this test's
                    pass
    good = sum(1 for f in results if not problems(f))
    print(f"\nSITL: {good} of {STARTS} starts fused within {FUSE_WITHIN_S} s of star's first pose and stayed on "
          f"star's pose (within {POSITION_TOL_M * 100:.0f} cm, {YAW_TOL_DEG} deg), samples dated at most "
          f"{MEDIAN_LAG_MS:.0f} ms old (median), {MAX_LAG_MS:.0f} ms (max)")
    bad = {k + 1: problems(f) for k, f in enumerate(results) if problems(f)}
    assert not bad, f"{len(bad)} of {STARTS} starts failed: {bad}"


def test_odometry_fused(star_bin, still, tmp_path):
    figures = one_start(star_bin, still, tmp_path, message="odometry")
    print("\nODOMETRY: " + report(figures))
    assert not problems(figures), problems(figures)
