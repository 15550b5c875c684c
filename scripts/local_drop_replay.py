#!/usr/bin/env python3
"""Replays the local contrast drop test over traced runs, with its reference
taken as the highest running mean of the last K tracked frames.

Reads runs of

    star localize DATASET ... -o RUN.txt --record RUN --record-every 0 \\
        --log star::localizer=trace > RUN.log 2>&1

Each sent frame's local contrast and running mean come from its `tracking
correlation` trace line, its error from the ground truth (TUM, matched by
stamp). For K = 0 (the mean itself) and a few larger K it prints how many
frames within 5 cm the test would refuse, and how many more than 10 cm off
it would catch, at the drop ratio `--drop` (0.7, `[keyframe]
lost_local_correlation_drop`). Frames are judged one by one on the runs as
they were: a refused frame would have changed what followed, so this is an
estimate of each rule's cost and reach, not a rerun.

Usage: scripts/local_drop_replay.py DATASET/groundtruth.txt RUN [RUN ...] [--drop 0.7]
"""

import math
import re
import sys

import numpy as np

from wrong_poses import read_tum  # this folder: stamp -> [tx ty tz qx qy qz qw]

ANSI = re.compile(r"\x1b\[[0-9;]*m")
FIELD = re.compile(r"(\w+)=(\S+)")
KS = [0, 1, 2, 3, 5, 8]


def number(text):
    try:
        return float(text)
    except (TypeError, ValueError):
        return math.nan


def frames_of(log):
    """[(stamp_s, local, mean)] in frame order; stamps as `star localize`
    records them (999 s + capture time)."""
    out, pending = [], None
    with open(log, errors="replace") as f:
        for line in f:
            line = ANSI.sub("", line)
            if "tracking correlation" in line:
                fields = dict(FIELD.findall(line))
                pending = (number(fields.get("local")), number(fields.get("local_mean")))
            elif "frame aligned" in line:
                fields = dict(FIELD.findall(line))
                stamp = round(999.0 + int(fields["capture_ns"]) * 1e-9, 3)
                if pending is not None:
                    out.append((stamp, *pending))
                pending = None
    return out


def main():
    args = sys.argv[1:]
    drop = 0.7
    if "--drop" in args:
        i = args.index("--drop")
        drop = float(args[i + 1])
        del args[i : i + 2]
    if len(args) < 2:
        sys.exit(__doc__)
    truth = read_tum(args[0])
    counts = {k: [0, 0, 0, 0] for k in KS}  # right, refused right, wrong, caught
    for run in args[1:]:
        sent = read_tum(run + ".txt")
        means = []
        for stamp, local, mean in frames_of(run + ".log"):
            if stamp not in sent or stamp not in truth:
                continue
            if math.isnan(local) or math.isnan(mean):
                means.append(mean)
                continue
            error_cm = float(np.linalg.norm(sent[stamp][:3] - truth[stamp][:3])) * 100.0
            for k in KS:
                reference = max([mean] + [m for m in means[max(0, len(means) - k) :] if k and not math.isnan(m)])
                refused = local < drop * reference
                c = counts[k]
                if error_cm < 5.0:
                    c[0] += 1
                    c[1] += refused
                elif error_cm > 10.0:
                    c[2] += 1
                    c[3] += refused
            means.append(mean)
    for k in KS:
        right, refused, wrong, caught = counts[k]
        name = "the mean" if k == 0 else f"highest of the last {k + 1} means"
        print(
            f"{name}: refuses {refused} of {right} frames within 5 cm, "
            f"catches {caught} of {wrong} over 10 cm"
        )


if __name__ == "__main__":
    main()
