#!/usr/bin/env python3
"""What relocalization's gate saw, per alignment, against the truth.

Reads the log of

    star bench reloc ... --log star::reloc::gate=trace,star::bench=debug > LOG 2>&1

where every alignment the gate judged is a `gate` line (its pose, inlier
ratio, gain, plain and local correlation, verdict) and every query ends with
a `query` line holding the truth. Each alignment is matched to the truth of
the query it belongs to (a `STAR_BENCH_VERBOSE=1` diagnosis after a query
counts for that query), then:

- alignments within 5 cm of the truth ("right") and more than 30 cm off
  ("wrong"): how many, and the range of each figure;
- the wrong ones with the highest local contrast, the right ones with the
  lowest plain correlation;
- per refused query, why: no alignment near the truth, the cheap figures
  (inlier ratio, visible ratio, residual, gain), or the correlations.

Usage: scripts/reloc_gate_figures.py LOG
"""

import math
import re
import sys
from collections import Counter

ANSI = re.compile(r"\x1b\[[0-9;]*m")
FIELD = re.compile(r"(\w+)=(\S+)")
RIGHT_M = 0.05
WRONG_M = 0.30


def parse(path):
    """[(accepted, truth xyz, [gate fields...])] per query, in order."""
    queries, pending = [], []
    with open(path, encoding="utf-8", errors="replace") as f:
        for line in f:
            line = ANSI.sub("", line)
            if "star::reloc::gate" in line:
                pending.append(dict(FIELD.findall(line)))
            elif "star::bench::reloc::recover" in line and " query " in line:
                q = dict(FIELD.findall(line))
                truth = tuple(float(q[f"truth_{a}_m"]) for a in "xyz")
                queries.append([q.get("accepted") == "true", truth, pending])
                pending = []
            elif re.match(r"\s+query \d+:", line) and queries:
                # The diagnosis printed after a query's own line.
                queries[-1][2].extend(pending)
                pending = []
    return queries


def num(g, key):
    try:
        return float(g[key])
    except (KeyError, ValueError):
        return math.nan


def off_m(truth, g):
    return math.dist(truth, (num(g, "x_m"), num(g, "y_m"), num(g, "z_m")))


def span(values):
    values = [v for v in values if not math.isnan(v)]
    return f"{min(values):.2f}-{max(values):.2f}" if values else "-"


def main():
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    queries = parse(sys.argv[1])
    if not queries:
        sys.exit(f"{sys.argv[1]}: no `query` lines; run the bench with "
                 "--log star::reloc::gate=trace,star::bench=debug")
    right, wrong = [], []
    for _, truth, gates in queries:
        for g in gates:
            d = off_m(truth, g)
            (right if d < RIGHT_M else wrong if d > WRONG_M else []).append(g)
    judged = lambda gs: [g for g in gs if not math.isnan(num(g, "all"))]
    print(f"{len(queries)} queries, {sum(len(q[2]) for q in queries)} alignments judged")
    for name, gs in (("right (< 5 cm)", right), ("wrong (> 30 cm)", wrong)):
        c = judged(gs)
        print(f"  {name}: {len(gs)}, {len(c)} past the cheap figures; "
              f"inliers {span(num(g, 'inliers') for g in gs)}, "
              f"plain {span(num(g, 'all') for g in c)}, "
              f"local {span(num(g, 'local') for g in c)}, "
              f"passed {sum(g.get('passes') == 'true' for g in gs)}")
    print("  wrong, highest local contrast:")
    for g in sorted(judged(wrong), key=lambda g: -num(g, "local"))[:5]:
        print(f"    local {num(g, 'local'):.2f} plain {num(g, 'all'):.2f} "
              f"inliers {num(g, 'inliers'):.2f} gain {num(g, 'gain'):.2f}")
    print("  right, lowest plain correlation:")
    for g in sorted(judged(right), key=lambda g: num(g, "all"))[:5]:
        print(f"    plain {num(g, 'all'):.2f} local {num(g, 'local'):.2f} "
              f"inliers {num(g, 'inliers'):.2f} gain {num(g, 'gain'):.2f}")
    why = Counter()
    for accepted, truth, gates in queries:
        if accepted:
            why["accepted"] += 1
            continue
        near = [g for g in gates if off_m(truth, g) < RIGHT_M]
        if not near:
            nearest = min((off_m(truth, g) for g in gates), default=math.inf)
            why["refused: no alignment within 5 cm"
                + (" (one within 30 cm)" if nearest <= WRONG_M else "")] += 1
        elif any(g.get("passes") == "true" for g in near):
            why["refused: a right alignment passed (rivals, twins)"] += 1
        elif not judged(near):
            why["refused: right alignments failed the cheap figures"] += 1
        else:
            why["refused: right alignments failed the correlations"] += 1
    print("  queries:")
    for k, v in sorted(why.items()):
        print(f"    {v:4d} {k}")


if __name__ == "__main__":
    main()
