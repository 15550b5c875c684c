#!/usr/bin/env python3
"""Why relocalization searches gave no pose, against the truth.

Reads the log of

    star bench reloc ... --log warn,star::bench::reloc::recover=debug,star::reloc::verify=debug > LOG 2>&1

where every alignment a search judged is a `candidate start aligned` line
(its pose, inlier ratio, visible ratio, residual, gain, correlations and
whether it passed the whole gate) and every query ends with a `query` line
holding the truth. The bench runs each query cold, then in its 2 m window,
so the queries alternate: cold, window, cold, ...

For each search that gave no pose it says what became of the truth:
- never aligned: no alignment came within 5 cm of it (retrieval);
- passed the gate, and a place more than 1 m away passed too (refused as
  ambiguous, or its rivals could not be checked);
- passed the gate and nothing elsewhere did (a pose the service does not
  hold: the lowered first level on a cold start, twins, refining renders);
- aligned, and the gate refused it: which of the cheap figures failed.

Then the pairs of places that both passed in one search (their local and
plain correlations), and what a gate whose inlier floor is divided by the
gain would let through: right and wrong alignments.

Usage: scripts/reloc_search_losses.py [--twin-checked] LOG [LOG...]

`--twin-checked`: the map is checked for geometric twins (a scan: `star
bench reloc` says "map occupancy built"), where the gate's inlier and
plain floors are `twin_checked_min_inlier_ratio` (0.5) and
`twin_checked_min_correlation` (0.2).
"""

import math
import re
import sys
from collections import Counter

ANSI = re.compile(r"\x1b\[[0-9;]*m")
FIELD = re.compile(r"(\w+)=(\S+)")
CORRELATIONS = re.compile(r"correlations=Some\(\(([^)]*)\)\)")
POSITION = re.compile(r"position_m=\[([^\]]*)\]")
RIGHT_M = 0.05
WRONG_M = 0.30
ELSEWHERE_M = 1.0
# `[reloc]` defaults (config/star.toml); `--twin-checked` lowers the first
# and MIN_PLAIN as the twin-checked gate does (`reloc::twins`).
MIN_INLIERS = 0.6
TWIN_CHECKED_MIN_INLIERS = 0.5
TWIN_CHECKED_MIN_PLAIN = 0.2
MIN_VISIBLE = 0.5
MAX_RESIDUAL = 12.0
GAIN = (0.25, 4.0)
MIN_PLAIN = 0.5
MIN_LOCAL_FIRST = 0.5


def parse(path):
    """[(accepted, truth xyz, [alignment dicts])] per query, in order."""
    queries, pending = [], []
    with open(path, encoding="utf-8", errors="replace") as f:
        for line in f:
            line = ANSI.sub("", line)
            if "candidate start aligned" in line:
                d = dict(FIELD.findall(line))
                c = CORRELATIONS.search(line)
                corr = [float(x) for x in c.group(1).split(",")] if c else [math.nan] * 5
                p = POSITION.search(line)
                if not p:
                    continue
                pending.append(
                    {
                        "inliers": float(d["inliers"]),
                        "visible": float(d["visible"]),
                        "residual": float(d["residual_gray"]),
                        "gain": float(d["gain"]),
                        "plain": corr[0],
                        "local": corr[2],
                        "passed": d.get("accepted") == "true",
                        "position": [float(x) for x in p.group(1).split(",")],
                    }
                )
            elif " query " in line and "recovery_ms=" in line:
                d = dict(FIELD.findall(line))
                truth = [float(d[k]) for k in ("truth_x_m", "truth_y_m", "truth_z_m")]
                queries.append((d.get("accepted") == "true", truth, pending))
                pending = []
    return queries


def cheap_failures(a, min_inliers=None):
    """The gate's cheap figures (and first-level correlations) `a` fails."""
    min_inliers = FLOORS["inliers"] if min_inliers is None else min_inliers
    why = []
    if a["inliers"] < min_inliers:
        why.append("inliers")
    if a["visible"] < MIN_VISIBLE:
        why.append("visible")
    if not a["residual"] <= MAX_RESIDUAL:
        why.append("residual")
    if not GAIN[0] <= a["gain"] <= GAIN[1]:
        why.append("gain")
    if not a["plain"] >= FLOORS["plain"]:
        why.append("plain")
    if not a["local"] >= MIN_LOCAL_FIRST:
        why.append("local")
    return why


def losses(queries):
    """What became of the truth in each search without a pose."""
    out, examples = Counter(), {}
    for accepted, truth, aligned in queries:
        if accepted:
            out["pose"] += 1
            continue
        right = [a for a in aligned if math.dist(a["position"], truth) < RIGHT_M]
        if any(a["passed"] for a in right):
            elsewhere = any(
                a["passed"] and math.dist(a["position"], truth) > ELSEWHERE_M for a in aligned
            )
            key = "truth passed, a place elsewhere too" if elsewhere else "truth passed, nothing elsewhere"
        elif right:
            best = max(right, key=lambda a: a["inliers"])
            why = cheap_failures(best) or ["correlation over the levels"]
            key = "truth aligned, gate refused: " + "+".join(why)
            examples.setdefault(key, []).append(
                "inliers %.2f gain %.2f plain %.2f local %.2f residual %.1f"
                % (best["inliers"], best["gain"], best["plain"], best["local"], best["residual"])
            )
        else:
            key = "truth never aligned"
        out[key] += 1
    return out, examples


FLOORS = {"inliers": MIN_INLIERS, "plain": MIN_PLAIN}


def main():
    args = sys.argv[1:]
    if "--twin-checked" in args:
        args.remove("--twin-checked")
        FLOORS.update(inliers=TWIN_CHECKED_MIN_INLIERS, plain=TWIN_CHECKED_MIN_PLAIN)
    if not args:
        sys.exit(__doc__)
    pairs = []
    scaled = Counter()
    for path in args:
        queries = parse(path)
        if not queries:
            sys.exit(f"{path}: no `query` lines (run with the log filter in this script's docs)")
        name = path.rsplit("/", 1)[-1]
        for kind, part in (("cold", queries[0::2]), ("window", queries[1::2])):
            counts, examples = losses(part)
            print(f"{name} {kind}: " + ", ".join(f"{k}: {v}" for k, v in sorted(counts.items())))
            for key, rows in examples.items():
                for row in rows:
                    print(f"    {key}: {row}")
        for q, (_, truth, aligned) in enumerate(queries):
            passed = [a for a in aligned if a["passed"]]
            for i, a in enumerate(passed):
                for b in passed[i + 1 :]:
                    if math.dist(a["position"], b["position"]) < ELSEWHERE_M:
                        continue
                    ea, eb = math.dist(a["position"], truth), math.dist(b["position"], truth)
                    pairs.append((name, q, ea, eb, a, b))
            for a in aligned:
                e = math.dist(a["position"], truth)
                old = not cheap_failures(a)
                new = not cheap_failures(a, FLOORS["inliers"] / max(1.0, a["gain"]))
                if new and not old:
                    scaled["right" if e < RIGHT_M else "wrong" if e > WRONG_M else "between"] += 1
    print(f"\npairs of places that both passed in one search: {len(pairs)}")
    for name, q, ea, eb, a, b in pairs:
        tag = "truth first" if ea < RIGHT_M else "truth second" if eb < RIGHT_M else "neither the truth"
        print(
            f"  {name} query {q}: {ea:.2f} m and {eb:.2f} m off, local {a['local']:.3f} / {b['local']:.3f}, "
            f"plain {a['plain']:.3f} / {b['plain']:.3f} ({tag})"
        )
    print(
        "\nan inlier floor of %.2f / max(1, gain) would pass, beyond today's gate: %d right, %d wrong, %d between"
        % (FLOORS["inliers"], scaled["right"], scaled["wrong"], scaled["between"])
    )


if __name__ == "__main__":
    main()
