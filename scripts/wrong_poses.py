#!/usr/bin/env python3
"""Where a run sent wrong poses, and what its lost tests saw there.

Joins one `star localize` run to the dataset's ground truth, frame by
frame, and prints each wrong pose (over 10 cm or 5 degrees, as
`star::offline::integrity` counts) with the frames around it. Each row
shows the state, the keyframe and its age, the frame's angle from the
keyframe, the jump from the prediction, the local contrast against its
running mean, and the error. The run must have been made with

    star localize DATASET ... -o RUN.txt --record RUN --record-every 0 \\
        --log star::localizer=trace > RUN.log 2>&1

Usage: scripts/wrong_poses.py DATASET/groundtruth.txt RUN [RUN ...]
           [--threshold-cm 10] [--context 5]

With several runs it also prints one summary line per run. Needs numpy.
"""

import argparse
import csv
import math
import re
import signal
import sys

import numpy as np

ANSI = re.compile(r"\x1b\[[0-9;]*m")
FIELD = re.compile(r"(\w+)=(\S+)")
WRONG_DEG = 5.0


def read_tum(path):
    """Stamp (rounded to 1 ms) -> [tx ty tz qx qy qz qw]."""
    poses = {}
    with open(path) as f:
        for line in f:
            if line.startswith("#") or not line.strip():
                continue
            v = [float(x) for x in line.split()]
            poses[round(v[0], 3)] = np.array(v[1:8])
    return poses


def angle_deg(qa, qb):
    """Angle between two unit quaternions (x y z w), degrees."""
    d = abs(float(np.dot(qa / np.linalg.norm(qa), qb / np.linalg.norm(qb))))
    return math.degrees(2.0 * math.acos(min(1.0, d)))


def read_trace(path):
    """capture_ns -> the fields of its `frame aligned` line, with the
    `tracking correlation` line logged just before it (prefixed `L_`) and
    the loss reason when the frame lost tracking."""
    frames, local, current = {}, {}, None
    with open(path, errors="replace") as f:
        for line in f:
            line = ANSI.sub("", line)
            if "tracking correlation" in line:
                local = {"L_" + k: v for k, v in FIELD.findall(line)}
            elif "frame aligned" in line:
                fields = dict(FIELD.findall(line))
                fields.update(local)
                local = {}
                current = int(fields["capture_ns"])
                frames[current] = fields
            elif "tracking lost" in line and current is not None:
                m = re.search(r'reason="([^"]*)"', line)
                frames[current]["lost"] = m.group(1) if m else "lost"
    return frames


def number(fields, key):
    try:
        return float(fields[key])
    except (KeyError, ValueError):
        return float("nan")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("groundtruth")
    ap.add_argument("runs", nargs="+", help="RUN: RUN.txt, RUN.log and RUN/frames.csv")
    ap.add_argument("--threshold-cm", type=float, default=10.0)
    ap.add_argument("--context", type=int, default=5, help="frames shown before each wrong pose")
    args = ap.parse_args()
    truth = read_tum(args.groundtruth)
    summary = []
    for run in args.runs:
        try:
            estimate = read_tum(run + ".txt")
            trace = read_trace(run + ".log")
            with open(run + "/frames.csv") as f:
                rows = list(csv.DictReader(f))
        except OSError as e:
            sys.exit(f"{run}: {e} (see the usage: scripts/wrong_poses.py --help)")
        errors = []
        for r in rows:
            stamp = round(float(r["stamp_s"]), 3)
            e, g = estimate.get(stamp), truth.get(stamp)
            if e is None or g is None:
                errors.append(None)
                continue
            errors.append((float(np.linalg.norm(e[:3] - g[:3])) * 100.0, angle_deg(e[3:], g[3:])))
        wrong = [
            i for i, e in enumerate(errors)
            if e is not None and (e[0] > args.threshold_cm or e[1] > WRONG_DEG)
        ]
        start = round(float(rows[0]["stamp_s"]), 3) if rows else 0.0
        shown = sorted({k for i in wrong for k in range(i - args.context, i + 3) if 0 <= k < len(rows)})
        print(f"== {run}: {len(wrong)} wrong of {sum(e is not None for e in errors)} sent")
        if shown:
            print("   t_s   state    keyframe age_ms from_kf_deg jump_cm dt_ms local/mean    error")
        previous = None
        for k in shown:
            if previous is not None and k != previous + 1:
                print("   ...")
            previous = k
            r, x, e = rows[k], trace.get(int(rows[k]["capture_ns"]), {}), errors[k]
            local, mean = number(x, "L_local"), number(x, "L_local_mean")
            ratio = f"{local:.2f}/{mean:.2f}" if not math.isnan(local) else "-"
            err = f"{e[0]:6.2f} cm {e[1]:4.2f} deg" if e else "-"
            print(
                f"{'>>' if k in wrong else '  '} {float(r['stamp_s']) - start:6.2f} {r['state']:8} "
                f"{r['keyframe_id']:>8} {float(r['keyframe_age_ms']):6.0f} {number(x, 'from_keyframe_deg'):11.1f} "
                f"{number(x, 'jump_m') * 100:7.1f} {number(x, 'dt_s') * 1000:5.0f} {ratio:>11} {err:>18} {x.get('lost', '')}"
            )
        sent = [e for e in errors if e is not None]
        summary.append((run, len(wrong), len(sent), max((e[0] for e in sent), default=0.0)))
    if len(summary) > 1:
        print()
        for run, n, sent, worst in summary:
            print(f"{run}: wrong {n} of {sent}, largest {worst:.2f} cm")


if __name__ == "__main__":
    signal.signal(signal.SIGPIPE, signal.SIG_DFL)  # quiet under `| head`
    main()
