#!/usr/bin/env python3
"""What holding each pose for the next frame would have sent, on runs as they were.

A pose is sent only once the next frame the tracker processes tracks too
(passes every lost test); a frame whose next one is lost is never sent.
The tracker's own state does not depend on what is sent, so the rule is
replayed exactly on recorded runs: it only removes poses. Prints, per run
and in all, the wrong poses sent (over 10 cm or 5 degrees, as
`star::offline::integrity` counts) as they were and under the rule, the
right poses the rule would not send, and the time each pose waits for its
next frame (the latency the rule adds). Each run must have been made with

    star localize DATASET ... -o RUN.txt --record RUN --record-every 0

Usage: scripts/next_frame_replay.py DATASET/groundtruth.txt RUN [RUN ...]
           [--threshold-cm 10]

Needs numpy.
"""

import argparse
import csv
import signal
import sys

import numpy as np

from wrong_poses import WRONG_DEG, angle_deg, read_tum  # the same truth, the same line

def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("groundtruth")
    ap.add_argument("runs", nargs="+", help="RUN: RUN.txt and RUN/frames.csv")
    ap.add_argument("--threshold-cm", type=float, default=10.0)
    args = ap.parse_args()
    truth = read_tum(args.groundtruth)
    totals = np.zeros(5, dtype=np.int64)  # sent, wrong, sent held, wrong held, right withheld
    waits_ms, runs_wrong, runs_wrong_held = [], 0, 0
    for run in args.runs:
        try:
            estimate = read_tum(run + ".txt")
            with open(run + "/frames.csv") as f:
                rows = list(csv.DictReader(f))
        except OSError as e:
            sys.exit(f"{run}: {e} (see the usage: scripts/next_frame_replay.py --help)")
        counts = np.zeros(5, dtype=np.int64)
        wrong_now, wrong_kept = [], []
        for i, r in enumerate(rows):
            stamp = round(float(r["stamp_s"]), 3)
            e, g = estimate.get(stamp), truth.get(stamp)
            if e is None or g is None:
                continue
            err_cm = float(np.linalg.norm(e[:3] - g[:3])) * 100.0
            wrong = err_cm > args.threshold_cm or angle_deg(e[3:], g[3:]) > WRONG_DEG
            nxt = rows[i + 1] if i + 1 < len(rows) else None
            kept = nxt is not None and nxt["state"] == "tracking"
            counts[0] += 1
            counts[1] += wrong
            if wrong:
                wrong_now.append(f"{stamp - float(rows[0]['stamp_s']):.2f} s {err_cm:.2f} cm")
            if kept:
                counts[2] += 1
                counts[3] += wrong
                if wrong:
                    wrong_kept.append(f"{stamp - float(rows[0]['stamp_s']):.2f} s {err_cm:.2f} cm")
                waits_ms.append((int(nxt["capture_ns"]) - int(r["capture_ns"])) * 1e-6)
            elif not wrong:
                counts[4] += 1
        totals += counts
        runs_wrong += counts[1] > 0
        runs_wrong_held += counts[3] > 0
        line = f"{run}: wrong {counts[1]} of {counts[0]} -> {counts[3]} of {counts[2]} held; right withheld {counts[4]}"
        if wrong_now:
            line += f"; wrong as sent: {', '.join(wrong_now)}; still sent: {', '.join(wrong_kept) or 'none'}"
        print(line)
    w = np.array(waits_ms) if waits_ms else np.zeros(1)
    print()
    print(f"{len(args.runs)} runs: wrong poses {totals[1]} of {totals[0]} sent, in {runs_wrong} runs; "
          f"held for the next frame: {totals[3]} of {totals[2]}, in {runs_wrong_held} runs; "
          f"right poses withheld {totals[4]} ({100.0 * totals[4] / max(totals[0], 1):.2f} %)")
    print(f"wait for the next frame: median {np.median(w):.1f} ms, p95 {np.percentile(w, 95):.1f} ms, "
          f"p99 {np.percentile(w, 99):.1f} ms, max {w.max():.1f} ms")


if __name__ == "__main__":
    signal.signal(signal.SIGPIPE, signal.SIG_DFL)  # quiet under `| head`
    main()
