"""NEES of the pose covariance star sends, against ground truth (a figure,
not a test): synthesizes a 150-frame sequence (preset `realistic` unless
given, seed 3 or NEES_SEED), replays 600 frames of it ping-pong through `star run`, takes
VISION_POSITION_ESTIMATE with the harness's autopilot (conftest.Autopilot),
and compares each pose (x y z in NED, roll pitch yaw) with ground truth
converted by the harness's own numpy transforms. Prints NEES per degree of
freedom (1 = the covariance fits the errors), the errors and the sent sigmas.

    STAR_BIN=target/release/star .venv/bin/python hil_tests/nees.py /tmp/nees [PRESET]
    MAVLINK_EXTRA='position_sigma_floor_m = 0;angle_sigma_floor_deg = 0' ...   # [mavlink] keys
    TRACKER_EXTRA='covariance_scale = 1' ...                                     # [tracker] keys
"""
import os
import pathlib
import subprocess
import sys

os.environ["MAVLINK20"] = "1"
import numpy as np  # noqa: E402

from conftest import (NED_FROM_WORLD, BODY_FROM_CAMERA, STAR, Autopilot, Rig, config_transform,  # noqa: E402
                      pingpong, read_tum, tum_matrix, vpe_world_from_camera, write_subset)

star = STAR
tmp = pathlib.Path(sys.argv[1]); tmp.mkdir(parents=True, exist_ok=True)
ds = tmp / "realistic"
# NEES_FRAMES=600 or more: that many frames synthesized and the first 600
# played once, with no reversal (a reversal at `aggressive`'s 2 m/s is a
# jump of 8 cm from the prediction, lost without a database).
frames = int(os.environ.get("NEES_FRAMES", "150"))
if not ds.exists():
    subprocess.run([str(star), "--log", "warn", "synth", "--preset", sys.argv[2] if len(sys.argv) > 2 else "realistic", str(ds), "--frames", str(frames), "--seed", os.environ.get("NEES_SEED", "3"), "--no-depth"], check=True)
seq = write_subset(ds, tmp / "pp", list(range(600))) if frames >= 600 else pingpong(ds, tmp / "pp", 600)
rig = Rig(star, tmp, seq)
extra = os.environ.get("MAVLINK_EXTRA", "")
if extra:
    rig.config.write_text(rig.config.read_text().replace("[mavlink]\n", "[mavlink]\n" + extra.replace(";", "\n") + "\n", 1))
tracker_extra = os.environ.get("TRACKER_EXTRA", "")
if tracker_extra:
    rig.config.write_text(rig.config.read_text().replace("[tracker]\n", "[tracker]\n" + tracker_extra.replace(";", "\n") + "\n", 1))
ap = Autopilot(rig.port).up()
try:
    run = rig.spawn(["run", "--config", str(rig.config), "--source", f"replay:{seq}", "--idle-exit-s", "1"], "run")
    run.communicate(timeout=200)
finally:
    ap.down(); rig.cleanup()
vpes = ap.of_type("VISION_POSITION_ESTIMATE")
stamps, gt = read_tum(seq / "groundtruth.txt")
N2W = config_transform(NED_FROM_WORLD); B2C = config_transform(BODY_FROM_CAMERA)
def ned_from_body_of(world_from_camera):
    return N2W @ world_from_camera @ np.linalg.inv(B2C)
def rpy_of(R):
    pitch = -np.arcsin(np.clip(R[2, 0], -1, 1)); roll = np.arctan2(R[2, 1], R[2, 2]); yaw = np.arctan2(R[1, 0], R[0, 0])
    return np.array([roll, pitch, yaw])
usec0 = vpes[0][1]["usec"]
# match by nearest GT pose in space among plausible frames: use time index instead
first = vpe_world_from_camera(vpes[0][1])
k0 = min(range(30), key=lambda k: np.linalg.norm(tum_matrix(gt[k])[:3, 3] - first[:3, 3]))
pos_nees, ang_nees, errs, sig, ep_all, ea_all, speeds = [], [], [], [], [], [], []
for _, f in vpes:
    k = k0 + round((f["usec"] - usec0) * 1e-6 * 50)
    if k >= len(gt): continue
    T = ned_from_body_of(tum_matrix(gt[k]))
    e_p = np.array([f["x"], f["y"], f["z"]]) - T[:3, 3]
    e_a = np.array([f["roll"], f["pitch"], f["yaw"]]) - rpy_of(T[:3, :3])
    e_a = (e_a + np.pi) % (2 * np.pi) - np.pi
    c = f["covariance"]
    if not np.isfinite(c[0]): continue
    P = np.zeros((6, 6)); idx = 0
    for r in range(6):
        for cc in range(r, 6):
            P[r, cc] = P[cc, r] = c[idx]; idx += 1
    pos_nees.append(e_p @ np.linalg.solve(P[:3, :3], e_p) / 3)
    ang_nees.append(e_a @ np.linalg.solve(P[3:, 3:], e_a) / 3)
    errs.append((np.linalg.norm(e_p), np.degrees(np.linalg.norm(e_a))))
    ep_all.append(e_p); ea_all.append(e_a)
    sig.append((np.sqrt(np.trace(P[:3, :3])), np.degrees(np.sqrt(np.trace(P[3:, 3:])))))
    a, b = tum_matrix(gt[max(k - 1, 0)]), tum_matrix(gt[min(k + 1, len(gt) - 1)])
    dt_s = (min(k + 1, len(gt) - 1) - max(k - 1, 0)) / 50
    turn = np.clip((np.trace(a[:3, :3].T @ b[:3, :3]) - 1) / 2, -1, 1)
    speeds.append((np.linalg.norm(b[:3, 3] - a[:3, 3]) / dt_s, np.degrees(np.arccos(turn)) / dt_s))
errs = np.array(errs); sig = np.array(sig)
print(f"preset {sys.argv[2] if len(sys.argv) > 2 else 'realistic'}, [mavlink] extra {os.environ.get('MAVLINK_EXTRA', '')!r}, [tracker] extra {tracker_extra!r}")
print(f"poses {len(pos_nees)}; NEES/dof position median {np.median(pos_nees):.2f} mean {np.mean(pos_nees):.2f}; angle median {np.median(ang_nees):.2f} mean {np.mean(ang_nees):.2f}")
print(f"error: position median {np.median(errs[:,0])*100:.3f} cm p95 {np.percentile(errs[:,0],95)*100:.3f} cm; angle median {np.median(errs[:,1]):.4f} deg p95 {np.percentile(errs[:,1],95):.4f} deg")
print(f"sent sigma (sqrt trace): position median {np.median(sig[:,0])*100:.4f} cm, angle median {np.median(sig[:,1]):.5f} deg")
ep_all = np.array(ep_all); ea_all = np.array(ea_all)
print("per-axis RMS error: position (x y z) cm", np.round(np.sqrt((ep_all**2).mean(0))*100, 4), "angle (r p y) deg", np.round(np.degrees(np.sqrt((ea_all**2).mean(0))), 5))
# By the true speed (terciles): whether the errors and the sent sigma grow together.
speeds = np.array(speeds); pos_nees = np.array(pos_nees); ang_nees = np.array(ang_nees)
for name, col in (("speed m/s", 0), ("turn rate deg/s", 1)):
    edges = np.percentile(speeds[:, col], [0, 100 / 3, 200 / 3, 100])
    for lo, hi in zip(edges[:-1], edges[1:]):
        m = (speeds[:, col] >= lo) & (speeds[:, col] <= hi)
        print(f"{name} {lo:.2f}-{hi:.2f}: poses {m.sum()}, NEES/dof position median {np.median(pos_nees[m]):.2f} angle {np.median(ang_nees[m]):.2f}; "
              f"error median {np.median(errs[m, 0]) * 100:.3f} cm {np.median(errs[m, 1]):.4f} deg; sigma median {np.median(sig[m, 0]) * 100:.4f} cm {np.median(sig[m, 1]):.5f} deg")
