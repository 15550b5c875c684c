#!/usr/bin/env python3
"""Errors of the poses sent first after a loss, against every other pose sent.

Reads runs of

    star localize DATASET ... -o RUN.txt --record RUN --record-every 0

(`RUN/frames.csv` gives each frame's state, `RUN.txt` the poses sent) and
the dataset's ground truth (TUM), matched by stamp. A frame is "first after a
loss" when it was sent and the frame before it was not tracking. Prints
how many such frames there were and how many were more than 10 cm off,
then the same for the frame after them and for every other frame sent.

Usage: scripts/resume_errors.py DATASET/groundtruth.txt RUN [RUN ...]
"""

import sys

import numpy as np

from wrong_poses import read_tum  # this folder: stamp -> [tx ty tz qx qy qz qw]

WRONG_CM = 10.0


def main():
    if len(sys.argv) < 3:
        sys.exit(__doc__)
    truth = read_tum(sys.argv[1])
    first, second, other = [], [], []
    for run in sys.argv[2:]:
        sent = read_tum(run + ".txt")
        with open(run + "/frames.csv") as f:
            rows = [line.strip().split(",") for line in f][1:]
        for i, row in enumerate(rows):
            stamp = round(float(row[0]), 3)
            if row[2] != "tracking" or stamp not in sent:
                continue
            g = truth.get(stamp)
            if g is None:
                continue
            error_cm = float(np.linalg.norm(sent[stamp][:3] - g[:3])) * 100.0
            if i >= 1 and rows[i - 1][2] != "tracking":
                first.append(error_cm)
            elif i >= 2 and rows[i - 2][2] != "tracking":
                second.append(error_cm)
            else:
                other.append(error_cm)
    for name, errors in [
        ("first sent after a loss", first),
        ("the frame after it", second),
        ("every other frame sent", other),
    ]:
        if not errors:
            print(f"{name}: none")
            continue
        over = sum(1 for e in errors if e > WRONG_CM)
        print(
            f"{name}: {len(errors)}, {over} over {WRONG_CM:.0f} cm; "
            f"median {np.median(errors):.2f} cm, max {max(errors):.2f} cm"
        )


if __name__ == "__main__":
    main()
