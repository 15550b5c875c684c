"""Link outages and relocalization jumps against ArduPilot's EKF3 (issue 20).

Same set-up as `test_sitl.py` (fresh ArduCopter SITL, EKF3 fed only by
star's vision on SERIAL1 through a TCP tap, `star run` replaying a still
camera), with the tap forwarding whole MAVLink frames:

- `test_link_blackouts`: after EKF3 fuses, the tap drops everything both
  ways for 2 s, then (6 s later) for 8 s: a link outage, star keeps running.
  After each, EKF3 must be back on star's pose (within BACK_TOL_M, and stay
  there) within BACK_WITHIN_S of the first pose that gets through, using
  external nav again if it had stopped, and the EKF height must never step
  by more than MAX_HEIGHT_STEP_M between two LOCAL_POSITION_NED samples
  (50 Hz) from the outage's start to 3 s after it.
- `test_relocalization_jump_follows_reset_counter`: the still camera
  teleports (frame 0, then frame TELEPORT_TO): star loses tracking,
  relocalizes from the map's database and sends the new pose with
  `reset_counter` + 1. EKF3 must follow to the new pose within
  FOLLOW_WITHIN_S and never leave the straight path from the old pose to
  the new one by more than GLITCH_TOL_M (no overshoot, no excursion).
  EKF3 flags only the first sample of a new reset_counter as a reset; when
  star sent the next pose right behind it (2 of 3 runs before star held the
  pose after a reset for one interval), EKF3 kept the newer one, lost the
  reset and overshot by 75 cm. The printed VISP records show the timing.
  EKF3 resets the position only: its yaw slews to the new heading (about
  22 deg/s, printed), which this test reports but does not check.

Figures are printed (`pytest -s`). Skips without the SITL binary.
"""

import math
import time

import numpy as np
import pytest

from conftest import Rig, read_tum, write_subset
from sitl import SKIP, Gcs, Sitl, Tap, free_instance, stop_all

pytestmark = SKIP

FPS = 50
# Poses before the first outage, between the two, and after the last.
LEAD_S = 4.0
BETWEEN_S = 6.0
TAIL_S = 5.0
BLACKOUTS_S = (2.0, 8.0)
BACK_WITHIN_S = 0.5
BACK_TOL_M = 0.02
MAX_HEIGHT_STEP_M = 0.05
# Seconds after a resume (or jump) the figures look at.
AFTER_S = 3.0

TELEPORT_TO = 110
BEFORE_JUMP_S = 6.0
AFTER_JUMP_S = 8.0
FOLLOW_WITHIN_S = 1.0
FOLLOW_TOL_M = 0.02
GLITCH_TOL_M = 0.05


def angle_deg(a, b):
    return abs(math.degrees(math.atan2(math.sin(a - b), math.cos(a - b))))


def position(fields):
    return (fields["x"], fields["y"], fields["z"])


def sent_before(poses, t):
    """The last pose star got through to SITL at or before `t`."""
    last = None
    for tp, f in poses:
        if tp > t:
            break
        last = f
    return last


def settle_time(samples, target_at, t_from, t_to, tol):
    """Seconds from `t_from` until the EKF position is within `tol` of
    `target_at(t)` and stays there until `t_to`; None if it never does."""
    window = [(t, p) for t, p in samples if t_from <= t <= t_to]
    if not window:
        return None
    settled = None
    for t, p in window:
        if math.dist(p, target_at(t)) <= tol:
            if settled is None:
                settled = t
        else:
            settled = None
    return None if settled is None else settled - t_from


def max_height_step(samples, t_from, t_to):
    zs = [p[2] for t, p in samples if t_from <= t <= t_to]
    return max((abs(b - a) for a, b in zip(zs, zs[1:])), default=float("nan"))


def max_horizontal_step(samples, t_from, t_to):
    xys = [p[:2] for t, p in samples if t_from <= t <= t_to]
    return max((math.dist(a, b) for a, b in zip(xys, xys[1:])), default=float("nan"))


def start_sitl(tmp):
    sitl = Sitl(free_instance(), tmp / "sitl")
    gcs = Gcs(sitl.gcs_port)
    gcs.start_streams()
    gcs.wait_text("EKF3 IMU0 tilt alignment complete", 40)
    return sitl, gcs


def wait_first_pose(tap, run, timeout_s=60):
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        poses = tap.of_type("VISION_POSITION_ESTIMATE")
        if poses:
            return poses[0][0]
        assert run.poll() is None, run.log_path.read_text()[-3000:]
        time.sleep(0.02)
    raise AssertionError(f"no pose from star in {timeout_s} s: {run.log_path.read_text()[-3000:]}")


@pytest.fixture(scope="module")
def long_still(dataset, tmp_path_factory):
    seconds = LEAD_S + sum(BLACKOUTS_S) + BETWEEN_S + TAIL_S + 3.0
    return write_subset(dataset, tmp_path_factory.mktemp("long") / "still", [0] * int(seconds * FPS))


def test_link_blackouts(star_bin, long_still, tmp_path):
    sitl, gcs = start_sitl(tmp_path)
    tap = None
    rig = Rig(star_bin, tmp_path, long_still)
    windows = []
    try:
        tap = Tap(sitl.serial1_port, frame_wise=True)
        run = rig.spawn(["run", "--config", str(rig.config), "--source", f"replay:{long_still}",
                         "--mavlink", f"tcpout:127.0.0.1:{tap.port}", "--idle-exit-s", "1"], "run")
        first = wait_first_pose(tap, run)
        gcs.wait_text("EKF3 IMU0 is using external nav data", 5)
        at = first + LEAD_S
        for duration in BLACKOUTS_S:
            time.sleep(max(0.0, at - time.monotonic()))
            tap.blackout.set()
            start = time.monotonic()
            time.sleep(duration)
            tap.blackout.clear()
            end = time.monotonic()
            windows.append((start, end))
            at = end + BETWEEN_S
        run.communicate(timeout=120)
        assert run.returncode == 0, run.log_path.read_text()[-3000:]
        time.sleep(0.3)
    finally:
        stop_all(sitl, rig, tap, gcs)

    poses = tap.of_type("VISION_POSITION_ESTIMATE")
    texts = gcs.texts
    failures = []
    for (start, end), duration in zip(windows, BLACKOUTS_S):
        dropped = [t for t, kind, _ in tap.dropped if kind == "VISION_POSITION_ESTIMATE" and start <= t <= end]
        resumed = [t for t, _ in poses if t >= end]
        assert resumed, f"no pose got through after the {duration} s outage (sequence too short?)"
        resume = resumed[0]
        last_sent = sent_before(poses, start)
        star_at = lambda t: position(sent_before(poses, t))  # noqa: E731
        drift = max((math.dist(p, position(last_sent)) for t, p in gcs.positions if start <= t <= resume),
                    default=float("nan"))
        back_s = settle_time(gcs.positions, star_at, resume, resume + AFTER_S, BACK_TOL_M)
        step = max_height_step(gcs.positions, start, resume + AFTER_S)
        step_xy = max_horizontal_step(gcs.positions, start, resume + AFTER_S)
        stopped = [x for t, x in texts if start <= t <= resume + AFTER_S and "stopped aiding" in x]
        using = [t - resume for t, x in texts
                 if resume <= t <= resume + AFTER_S and "is using external nav data" in x]
        after = [math.dist(p, star_at(t)) for t, p in gcs.positions if resume + 1.0 <= t <= resume + AFTER_S]
        print(f"\nblackout {duration:.0f} s: {len(dropped)} poses dropped by the tap, EKF drift during it "
              f"{drift * 100:.2f} cm, texts {stopped + [x for t, x in texts if start <= t <= resume + AFTER_S and 'external nav' in x]}, "
              f"external nav announced again {['%.3f s' % u for u in using]} after the resume, "
              f"back within {BACK_TOL_M * 100:.0f} cm after "
              f"{'never' if back_s is None else '%.3f s' % back_s}, largest height step "
              f"{step * 100:.2f} cm (horizontal {step_xy * 100:.2f} cm; a step of about the drift is EKF3 resetting "
              f"onto the resumed vision), "
              f"largest error 1-3 s after {max(after, default=float('nan')) * 100:.2f} cm")
        if len(dropped) < duration * FPS * 0.8:
            failures.append(f"{duration} s outage dropped only {len(dropped)} poses")
        if back_s is None or back_s > BACK_WITHIN_S:
            failures.append(f"{duration} s outage: EKF back on star's pose after {back_s} s")
        if stopped and not using:
            failures.append(f"{duration} s outage: EKF3 stopped aiding and did not use external nav again")
        if not step <= MAX_HEIGHT_STEP_M:
            failures.append(f"{duration} s outage: EKF height stepped {step * 100:.2f} cm")
    assert not failures, failures


@pytest.fixture(scope="module")
def teleport(dataset, tmp_path_factory):
    order = [0] * int(BEFORE_JUMP_S * FPS) + [TELEPORT_TO] * int(AFTER_JUMP_S * FPS)
    return write_subset(dataset, tmp_path_factory.mktemp("teleport") / "teleport", order)


def segment_distance(p, a, b):
    p, a, b = (np.asarray(v, float) for v in (p, a, b))
    ab = b - a
    s = np.clip(np.dot(p - a, ab) / max(np.dot(ab, ab), 1e-12), 0.0, 1.0)
    return float(np.linalg.norm(p - (a + s * ab)))


def test_relocalization_jump_follows_reset_counter(star_bin, dataset, teleport, reloc_db, tmp_path):
    _, gt = read_tum(dataset / "groundtruth.txt")
    jump_gt_m = float(np.linalg.norm(gt[TELEPORT_TO][:3] - gt[0][:3]))
    sitl, gcs = start_sitl(tmp_path)
    tap = None
    rig = Rig(star_bin, tmp_path, teleport)
    try:
        rig.write_config(f'[reloc]\ndatabase = "{reloc_db}"')
        tap = Tap(sitl.serial1_port)
        run = rig.spawn(["run", "--config", str(rig.config), "--source", f"replay:{teleport}",
                         "--mavlink", f"tcpout:127.0.0.1:{tap.port}", "--idle-exit-s", "1"], "run")
        wait_first_pose(tap, run)
        run.communicate(timeout=120)
        assert run.returncode == 0, run.log_path.read_text()[-3000:]
        time.sleep(0.3)
    finally:
        stop_all(sitl, rig, tap, gcs)

    poses = tap.of_type("VISION_POSITION_ESTIMATE")
    counters = [f["reset_counter"] for _, f in poses]
    assert counters == sorted(counters), f"reset_counter decreased: {sorted(set(counters))}"
    assert counters[0] != counters[-1], (
        f"no reset_counter change in {len(poses)} poses: {rig.tmp / 'run.log'}")
    k = next(i for i, c in enumerate(counters) if c != counters[0])
    t_jump, new = poses[k]
    old = poses[k - 1][1]
    gap_s = t_jump - poses[k - 1][0]
    jump_m = math.dist(position(old), position(new))
    new_at = lambda t: position(sent_before(poses, t))  # noqa: E731
    follow_s = settle_time(gcs.positions, new_at, t_jump, t_jump + AFTER_S, FOLLOW_TOL_M)
    excursion = max((segment_distance(p, position(old), position(new))
                     for t, p in gcs.positions if t_jump <= t <= t_jump + AFTER_S), default=float("nan"))
    texts = [x for t, x in gcs.texts if t >= poses[k - 1][0]]
    # Yaw: EKF3 resets its position on a reset_counter change, not its yaw.
    yaw_new = new["yaw"]
    yaw_errs = [(t - t_jump, angle_deg(y, yaw_new)) for t, y in gcs.attitudes if t >= t_jump]
    yaw_at = {s: next((e for dt, e in yaw_errs if dt >= s), float("nan")) for s in (0.1, 1.0, 3.0)}
    yaw_within_5 = next((dt for dt, e in yaw_errs if e <= 5.0), None)
    print(f"\nrelocalization jump: reset_counter {counters[k - 1]} -> {counters[k]} "
          f"({sorted(set(counters))} in all), no pose for {gap_s:.2f} s (lost, relocalizing), "
          f"pose jump {jump_m:.3f} m (ground truth {jump_gt_m:.3f} m), EKF within "
          f"{FOLLOW_TOL_M * 100:.0f} cm of the new pose after "
          f"{'never' if follow_s is None else '%.3f s' % follow_s}, largest distance from the old-new "
          f"segment {excursion * 100:.2f} cm, texts since: {texts}; yaw jump "
          f"{angle_deg(old['yaw'], yaw_new):.1f} deg: EKF yaw error {yaw_at[0.1]:.1f} / {yaw_at[1.0]:.1f} / "
          f"{yaw_at[3.0]:.1f} deg at +0.1 / 1 / 3 s, within 5 deg after "
          f"{'never (in the run)' if yaw_within_5 is None else '%.2f s' % yaw_within_5}")
    # The EKF against star every 0.2 s around the jump, for the record.
    for t, p in gcs.positions[::10]:
        if t_jump - 0.3 <= t <= t_jump + 1.0:
            yaw = next((y for ty, y in gcs.attitudes if ty >= t), float("nan"))
            sent = sent_before(poses, t)
            print(f"  t{t - t_jump:+.2f} s  EKF ({p[0]:+.3f} {p[1]:+.3f} {p[2]:+.3f}) yaw {math.degrees(yaw):+.1f}"
                  f"  star ({sent['x']:+.3f} {sent['y']:+.3f} {sent['z']:+.3f}) yaw {math.degrees(sent['yaw']):+.1f}"
                  f"  reset_counter {sent['reset_counter']}")
    # SITL's own record of the samples around the reset: when it received
    # them (TimeUS), star's usec (RTimeUS), the corrected time EKF3 used
    # (CTimeMS), the reset counter (Rst) and whether it ignored them (Ign).
    visp = [r for r in sitl.log_rows(["VISP"])]
    k_log = next((i for i, r in enumerate(visp) if r.get("Rst") != visp[0].get("Rst")), None)
    if k_log is not None:
        for r in visp[max(0, k_log - 3):k_log + 4]:
            print(f"  VISP TimeUS {r['TimeUS']} RTimeUS {r['RTimeUS']} CTimeMS {r['CTimeMS']} "
                  f"Rst {r.get('Rst')} Ign {r.get('Ign')} PX {r['PX']:+.3f} PY {r['PY']:+.3f}")
    assert jump_m > 0.3, f"the teleport moved star's pose only {jump_m:.3f} m"
    assert follow_s is not None and follow_s <= FOLLOW_WITHIN_S, f"EKF followed after {follow_s} s"
    assert excursion <= GLITCH_TOL_M, f"EKF left the old-new path by {excursion * 100:.2f} cm"
