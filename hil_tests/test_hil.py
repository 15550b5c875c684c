"""Hardware-in-the-loop scenarios: `star camera` (replay) and `star track` as
separate processes, the harness as the autopilot (see conftest.py).

Scenario numbers follow issue 8.
"""

import glob
import math
import os
import pathlib
import signal
import subprocess
import time

import numpy as np
import pytest

from conftest import (FPS, FRAMES, SPEED, pingpong, pose_error, read_tum, tum_matrix, vpe_world_from_camera,
                      write_subset)

POSITION_TOL_M = 0.03
ROTATION_TOL_DEG = 0.5


def associate(vpes, gt_poses):
    """GT index of each VPE: the first is matched in space among the first
    ten frames, the others by `usec` (capture time) at 50 Hz."""
    est = [vpe_world_from_camera(f) for _, f in vpes]
    first = min(range(min(10, len(gt_poses))),
                key=lambda k: pose_error(tum_matrix(gt_poses[k]), est[0])[0])
    usec0 = vpes[0][1]["usec"]
    return est, [first + round((f["usec"] - usec0) * 1e-6 * FPS * SPEED) for _, f in vpes]


def check_accuracy(vpes, gt_poses):
    est, idx = associate(vpes, gt_poses)
    errors = [pose_error(tum_matrix(gt_poses[k]), e) for e, k in zip(est, idx) if k < len(gt_poses)]
    t_max = max(e[0] for e in errors)
    r_max = max(e[1] for e in errors)
    assert t_max <= POSITION_TOL_M, f"position error up to {t_max * 100:.2f} cm"
    assert r_max <= ROTATION_TOL_DEG, f"rotation error up to {r_max:.3f} deg"
    return t_max, r_max


def check_fields(vpes):
    usecs = [f["usec"] for _, f in vpes]
    assert all(b > a for a, b in zip(usecs, usecs[1:])), "usec not strictly increasing"
    for _, f in vpes:
        cov = np.array([float(v) for v in f["covariance"]])
        assert cov.shape == (21,) and np.all(np.isfinite(cov)), f"covariance {cov}"
        assert all(cov[d] > 0 for d in (0, 6, 11, 15, 18, 20)), f"covariance diagonal {cov}"
        assert f["reset_counter"] == 0


def summary_line(proc):
    out, _ = proc.communicate(timeout=10)
    return out


# (1) nominal -------------------------------------------------------------

def test_nominal(rig, autopilot):
    autopilot.up()
    track = rig.start_tracker("--idle-exit-s", "1")
    camera = rig.start_camera()
    assert camera.wait(timeout=30) == 0
    out = summary_line(track)
    assert track.returncode == 0, track.log_path.read_text()[-2000:]
    time.sleep(0.2)
    autopilot.down()
    vpes = autopilot.of_type("VISION_POSITION_ESTIMATE")
    beats = autopilot.of_type("HEARTBEAT")
    assert autopilot.bad_data == 0
    assert len(beats) >= 2, f"{len(beats)} heartbeats"
    assert all(f["type"] == 18 and f["autopilot"] == 8 for _, f in beats)
    assert len(vpes) >= 0.95 * FRAMES, f"{len(vpes)} poses for {FRAMES} frames: {out}"
    check_fields(vpes)
    _, gt = read_tum(rig.dataset / "groundtruth.txt")
    check_accuracy(vpes, gt)
    # Our TIMESYNC answers are in CLOCK_MONOTONIC, so usec is the capture
    # time: a pose arrives after its capture, and soon.
    lag_ms = [(t / 1e3 - f["usec"]) / 1e3 for t, f in vpes]
    assert min(lag_ms) > -2 and np.median(lag_ms) < 50, f"lag {min(lag_ms)}..{max(lag_ms)} ms"


# (2) blackout / teleport -------------------------------------------------

@pytest.mark.parametrize("fault", ["blackout", "teleport"])
def test_blackout_and_teleport_increments_reset_counter(rig, autopilot, dataset, reloc_db, tmp_path, fault):
    """A 1 s blackout (black frames while the camera keeps moving), or a jump
    to a far part of the sequence: the tracker is lost, sends nothing,
    relocalizes from the database, and resumes within 1 s with
    reset_counter + 1 and poses within 5 cm of ground truth."""
    if fault == "blackout":
        # 40 frames, 50 black ones (1 s) during which the camera moves on.
        order, black, resume_at = list(range(FRAMES)), range(40, 90), 90
    else:
        order, black, resume_at = list(range(0, 40)) + list(range(110, FRAMES)), (), 40
    faulty = write_subset(dataset, tmp_path / fault, order, black=black)
    rig.dataset = faulty
    rig.write_config(f'[reloc]\ndatabase = "{reloc_db}"')
    autopilot.up()
    track = rig.start_tracker("--idle-exit-s", "1")
    assert rig.start_camera(faulty).wait(timeout=30) == 0
    assert track.wait(timeout=30) == 0
    out = track.stdout.read()
    autopilot.down()
    vpes = autopilot.of_type("VISION_POSITION_ESTIMATE")
    assert vpes, "no VISION_POSITION_ESTIMATE received"
    counters = [f["reset_counter"] for _, f in vpes]
    assert counters[0] == 0 and counters[-1] == 1, (
        f"reset_counter went {sorted(set(counters))}: {out}\n{track.log_path.read_text()[-1500:]}")
    assert counters == sorted(counters), "reset_counter decreased"
    stamps, gt = read_tum(faulty / "groundtruth.txt")
    usec0 = vpes[0][1]["usec"]
    # The first pose goes out once the start pose is verified, a frame or a
    # few in: its frame is the one it matches in space among the first ones.
    first_pose = vpe_world_from_camera(vpes[0][1])
    k0 = min(range(min(30, len(gt))), key=lambda k: pose_error(tum_matrix(gt[k]), first_pose)[0])
    # Frame index of each message, from `usec` (capture time) at the replay rate.
    index = [k0 + round((f["usec"] - usec0) * 1e-6 * FPS * SPEED) for _, f in vpes]
    before = [k for k, (_, f) in zip(index, vpes) if f["reset_counter"] == 0]
    after = [(k, f) for k, (_, f) in zip(index, vpes) if f["reset_counter"] == 1]
    # Nothing while lost: no message stamped in the fault, none out of order.
    assert max(before) < resume_at, f"a pose was sent for frame {max(before)} during the fault"
    first_after = after[0][0]
    assert resume_at <= first_after <= resume_at + FPS, (
        f"resumed at frame {first_after}, more than 1 s after the fault ended at {resume_at}")
    # After recovery: within 5 cm of ground truth (the frame matched in space
    # among the frames after the fault, so the test does not rely on `usec`).
    errs = [min(pose_error(tum_matrix(g), vpe_world_from_camera(f))[0] for g in gt[resume_at:])
            for _, f in after]
    assert max(errs) <= 0.05, f"pose after recovery off by up to {max(errs) * 100:.1f} cm"


# (3) camera killed and restarted ------------------------------------------

def test_camera_restart(rig, autopilot, dataset, tmp_path):
    autopilot.up()
    track = rig.start_tracker()
    camera = rig.start_camera()
    time.sleep(1.2)
    camera.send_signal(signal.SIGKILL)
    camera.wait()
    killed_at = time.monotonic_ns()
    time.sleep(1.0)
    assert track.poll() is None, "tracker died with the camera"
    before = autopilot.of_type("VISION_POSITION_ESTIMATE")
    assert len(before) > 20
    # Restart where the camera stopped (the last pose the autopilot got),
    # as a camera restarted in flight would see the scene.
    _, gt = read_tum(dataset / "groundtruth.txt")
    last = vpe_world_from_camera(before[-1][1])
    k = min(range(FRAMES), key=lambda i: pose_error(tum_matrix(gt[i]), last)[0])
    tail = write_subset(dataset, tmp_path / "tail", list(range(k, FRAMES)))
    camera2 = rig.start_camera(tail)
    assert camera2.wait(timeout=30) == 0
    time.sleep(0.5)
    assert track.poll() is None, "tracker died after the camera restart"
    track.send_signal(signal.SIGTERM)
    out = summary_line(track)
    assert track.returncode == 0
    assert "camera restarts 1" in out, out
    autopilot.down()
    # After the restart by capture time (usec is CLOCK_MONOTONIC: our TIMESYNC
    # answers are), not by arrival: the pose of the killed camera's last
    # frame can arrive just after the kill.
    after = [(t, f) for t, f in autopilot.of_type("VISION_POSITION_ESTIMATE")
             if f["usec"] * 1000 > killed_at]
    # Resumed: most frames after the restart give a pose (the first ones may
    # be lost while the tracker re-converges; the rate is scenario 1's job).
    assert len(after) >= 0.5 * (FRAMES - k), f"{len(after)} poses after the restart, {FRAMES - k} frames"
    _, gt_tail = read_tum(tail / "groundtruth.txt")
    check_accuracy(after, gt_tail)


# (4) autopilot link absent, appears, disappears, returns -------------------

def test_link_absent_appears_disappears(rig, autopilot, dataset, tmp_path):
    rig.dataset = pingpong(dataset, tmp_path / "pingpong", int(10 * FPS * SPEED))
    rig.write_config()
    track = rig.start_tracker()
    rig.start_camera()
    time.sleep(1.5)  # no autopilot yet
    assert track.poll() is None
    autopilot.up()
    time.sleep(2.0)
    autopilot.down()
    first_window = len(autopilot.records)
    time.sleep(1.5)  # link gone again
    assert track.poll() is None, "tracker died when the link went away"
    back_at = time.monotonic_ns()
    autopilot.up()
    time.sleep(1.5)
    autopilot.down()
    assert track.poll() is None
    track.send_signal(signal.SIGTERM)
    summary_line(track)
    assert track.returncode == 0
    vpes = autopilot.of_type("VISION_POSITION_ESTIMATE")
    assert first_window > 0 and any(t > back_at for t, _ in vpes), "no poses after the link returned"
    # No stale burst: every pose is fresh when it arrives (max_pose_age_ms
    # is 100), and the link never delivers more than the camera rate.
    ages_ms = [(t / 1e3 - f["usec"]) / 1e3 for t, f in vpes]
    assert max(ages_ms) < 150, f"stale pose delivered, {max(ages_ms):.0f} ms old"
    returned = sorted(t for t, _ in vpes if t > back_at)
    first_100ms = [t for t in returned if t - returned[0] < 100_000_000]
    assert len(first_100ms) <= 7, f"{len(first_100ms)} poses in the first 100 ms after the link returned"


# (5) bad inputs -------------------------------------------------------------

@pytest.mark.parametrize("case", ["malformed", "missing_mesh", "missing_config", "bad_source"])
def test_bad_inputs_exit_non_zero_with_message(rig, case):
    cfg = rig.config
    if case == "malformed":
        cfg.write_text("[tracker\npyramid_levels = 3\n")
        args, needle = ["track", "--config", str(cfg)], str(cfg)
    elif case == "missing_mesh":
        rig.write_config()
        cfg.write_text(cfg.read_text().replace(str(rig.dataset / "map" / "map.obj"), "/nonexistent/map.obj"))
        args, needle = ["track", "--config", str(cfg)], "/nonexistent/map.obj"
    elif case == "missing_config":
        args, needle = ["track", "--config", "/nonexistent/star.toml"], "/nonexistent/star.toml"
    else:
        args, needle = ["camera", "--config", str(cfg), "--source", "replay:/nonexistent/ds"], "/nonexistent/ds"
    p = subprocess.run([rig.star, *args], capture_output=True, text=True, timeout=30)
    assert p.returncode != 0
    assert needle in p.stderr, p.stderr
    assert "panicked" not in p.stderr
    # iceoryx2 keeps one small global management segment per prefix; no
    # node, service or port may be left behind.
    left = [f for f in glob.glob(f"/dev/shm/{rig.prefix}*") if not f.endswith(".global_mgmt")]
    assert not left, f"left in /dev/shm: {left}"


# (6) soak -------------------------------------------------------------------

def rss_kib(pid):
    for line in open(f"/proc/{pid}/status"):
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    return 0


# The soak's drop count starts this long after the first pose went out.
WARM_UP_S = 1.0


def cpu_counters():
    """(steal, all) jiffies of the machine, from /proc/stat: a host that
    takes the vCPUs away shows as steal."""
    fields = [int(v) for v in open("/proc/stat").readline().split()[1:]]
    return fields[7] if len(fields) > 7 else 0, sum(fields)


def drop_report(record_dir, period_ns):
    """Where the frames went missing, from the flight log (`frames.csv`):
    each gap in capture times of more than one period, when it began (s into
    the run), how many frames it lost, and the latency (pose sent - capture)
    and tracking time of the frames either side. A tracker that cannot keep
    up shows long tracking times before its gaps; a machine that stalled
    the processes shows short ones and a long latency across the gap."""
    lines = (record_dir / "frames.csv").read_text().splitlines()
    head = lines[0].split(",")
    col = {name: i for i, name in enumerate(head)}
    rows = [r.split(",") for r in lines[1:] if r]
    cap = [int(r[col["capture_ns"]]) for r in rows]
    track_ms = [float(r[col["track_ms"]]) for r in rows]

    def latency_ms(i):
        sent = rows[i][col["mavlink_send_ns"]]
        return f"{(int(sent) - cap[i]) / 1e6:.1f}" if sent else "-"

    missed = frames_missed(cap, period_ns)
    gaps = []
    for i in range(1, len(cap)):
        if missed[i] > 0:
            gaps.append(f"t={(cap[i - 1] - cap[0]) / 1e9:.1f}s lost {missed[i]} "
                        f"(before: track {track_ms[i - 1]:.1f} ms, latency {latency_ms(i - 1)} ms; "
                        f"after: latency {latency_ms(i)} ms)")
    slow = sum(1 for t in track_ms if t * 1e6 > period_ns)
    text = (f"{len(gaps)} gaps; {slow} of {len(rows)} frames tracked in more than a period; "
            f"max track {max(track_ms, default=0):.1f} ms; gaps: " + "; ".join(gaps[:30]))
    return text, steady_missed(cap, missed, [bool(r[col["mavlink_send_ns"]]) for r in rows])


def frames_missed(capture_ns, period_ns):
    """Per row, the frames missing between it and the row before (0 for the
    first)."""
    return [0] + [max(0, round((b - a) / period_ns) - 1) for a, b in zip(capture_ns, capture_ns[1:])]


def steady_missed(capture_ns, missed, pose_sent, warm_up_s=WARM_UP_S):
    """(frames missed during the start, frames missed after it). The start
    runs to `warm_up_s` after the first pose the autopilot received: the
    boot gate verifies the start, and the first tracking frames set up the
    keyframes (50-150 ms each with 3 busy loops beside the tracker). A
    frame that arrives meanwhile is replaced by the newest, as it should
    be."""
    first = next((i for i, sent in enumerate(pose_sent) if sent), None)
    steady_from_ns = (capture_ns[first] + warm_up_s * 1e9) if first is not None else math.inf
    start = sum(m for i, m in enumerate(missed) if i > 0 and capture_ns[i - 1] < steady_from_ns)
    return start, sum(missed) - start


@pytest.mark.soak
def test_soak(rig, autopilot, dataset, tmp_path):
    """STAR_SOAK_S seconds (default 15; CI sets 120) at 50 Hz: no RSS growth,
    at most 0.1 % of frames dropped."""
    duration_s = float(os.environ.get("STAR_SOAK_S", "15"))
    rig.dataset = pingpong(dataset, tmp_path / "pingpong", int((duration_s + 5) * FPS * SPEED))
    rig.write_config()
    autopilot.up()
    record = tmp_path / "record"
    # The flight log's rows only (no PNGs: the soak's load stays the tracker's).
    track = rig.start_tracker("--record", str(record), "--record-every", "0")
    steal0, all0 = cpu_counters()
    camera = rig.start_camera()
    samples = []
    end = time.monotonic() + duration_s
    while time.monotonic() < end:
        time.sleep(0.5)
        assert track.poll() is None and camera.poll() is None
        samples.append(rss_kib(track.pid))
    camera.send_signal(signal.SIGTERM)
    camera.wait(timeout=5)
    time.sleep(0.3)
    track.send_signal(signal.SIGTERM)
    out = summary_line(track)
    assert track.returncode == 0
    autopilot.down()
    # A row the recorder's queue dropped shows as a gap in the flight log.
    log_line = next((line for line in out.splitlines() if "dropped rows " in line), "")
    rows_dropped = int(log_line.split("dropped rows ")[1].split()[0]) if log_line else 0
    # The frame counts' line.
    out = next((line for line in out.splitlines() if "frames processed" in line), out)
    processed = int(out.split("frames processed ")[1].split()[0])
    dropped = int(out.split("dropped ")[1].split()[0])
    rejected = int(out.split("rejected ")[1].split()[0])
    assert rejected == 0, out
    assert processed >= 0.9 * duration_s * FPS * SPEED, out
    # 0.1 %, in whole frames: at the local default of 15 s (750 frames) one
    # frame may go (a 2-core machine drops one now and then: 1-2 of 750
    # with the binaries before and after 2026-11-27's change alike).
    # Counted from WARM_UP_S after the first pose sent on: until then the
    # boot gate verifies the start and the first keyframes are set up, and
    # on a loaded machine those first frames take 50-150 ms (3 busy loops
    # beside it: 4-8 frames missed, all in the first 0.2 s). The start is
    # bounded by `processed` above.
    allowed = math.ceil(0.001 * (processed + dropped))
    steal1, all1 = cpu_counters()
    steal_pct = 100.0 * (steal1 - steal0) / max(1, all1 - all0)
    report, (missed_start, missed_steady) = drop_report(record, 1e9 / (FPS * SPEED))
    context = (f"{out.strip()}; CPU steal {steal_pct:.1f} % during the soak; "
               f"{missed_start} frames missed until {WARM_UP_S} s after the first pose, "
               f"{missed_steady} after; {report}")
    print(f"soak: {context}")
    # The flight log sees every gap the tracker's counter does.
    assert missed_start + missed_steady == dropped + rows_dropped, f"rows dropped {rows_dropped}; {context}"
    assert missed_steady <= allowed, (
        f"{missed_steady} of {processed + dropped} frames dropped after the start "
        f"(allowed {allowed}); {context}"
    )
    # RSS: after the first quarter (warm-up), no growth beyond 2 MiB.
    warm = samples[len(samples) // 4:]
    growth = max(warm) - warm[0]
    assert growth <= 2048, f"RSS grew by {growth} KiB: {warm[0]} -> {max(warm)} KiB; samples {samples}"
    vpes = autopilot.of_type("VISION_POSITION_ESTIMATE")
    assert len(vpes) >= 0.95 * processed, f"{len(vpes)} poses for {processed} frames"


# (7) v4l2loopback -----------------------------------------------------------

def loopback_devices():
    found = []
    for name in glob.glob("/sys/class/video4linux/video*/name"):
        if "loopback" in pathlib.Path(name).read_text().lower():
            found.append("/dev/" + pathlib.Path(name).parent.name)
    return found


def test_v4l2loopback_path(rig, autopilot, dataset):
    devices = loopback_devices()
    if not devices:
        pytest.skip("no v4l2loopback device (/dev/video* with a Loopback driver): "
                    "`sudo modprobe v4l2loopback exclusive_caps=1` to run this scenario")
    dev = devices[0]
    autopilot.up()
    replay = subprocess.Popen([rig.star, "replay", str(dataset), "--device", dev, "--loop"],
                              stderr=subprocess.DEVNULL)
    rig.procs.append(replay)
    time.sleep(1.0)
    track = rig.start_tracker()
    rig.spawn(["camera", "--config", str(rig.config), "--source", f"v4l2:{dev}"], "camera")
    time.sleep(4.0)
    assert track.poll() is None
    assert len(autopilot.of_type("VISION_POSITION_ESTIMATE")) > 0
    assert math.isfinite(0.0)


def test_wrong_size_frames_are_rejected_and_counted(rig):
    """(5, continued) A camera publishing frames of another size: the tracker
    rejects and counts them, keeps running, stops on SIGTERM with its
    summary, and exits 1 saying it tracked nothing (issue 24: a run that
    tracked nothing fails)."""
    track = rig.start_tracker()
    camera = rig.spawn(["camera", "--config", str(rig.config), "--source", "pattern:320x240",
                        "--frames", "20"], "camera")
    assert camera.wait(timeout=20) == 0
    time.sleep(0.5)
    assert track.poll() is None, "tracker died on bad frames"
    track.send_signal(signal.SIGTERM)
    out = summary_line(track)
    assert track.returncode == 1, out
    assert "tracked nothing" in track.log_path.read_text(), track.log_path.read_text()[-2000:]
    rejected = int(out.split("rejected ")[1].split()[0])
    assert rejected >= 10, out
    wrong_size = int(out.split("(wrong size ")[1].split(")")[0])
    assert wrong_size == rejected, out
    assert "frames processed 0" in out, out
