"""Closed-loop flight on vision in ArduPilot SITL (issue 20): the vehicle
flies on what star sees.

`flight.fly` (see its docstring for the set-up): GPS off, EKF3 on star's
VISION_POSITION_ESTIMATE only; `star camera --source sim:` renders the
vehicle's camera at SITL's true pose (320 x 256, the `realistic` sensor
model, 50 Hz); `star track` tracks it. The test is the ground station: it
sets the EKF origin (SET_GPS_GLOBAL_ORIGIN) before arming, arms in GUIDED,
takes off to 1 m, flies a 2 m square at 0.5 m/s (stopping at each corner,
heading held) and lands.

Checked, from arming to disarming:
- the flight happened: the true path reached every corner of the square
  (within CORNER_TOL_M) and the vehicle landed and disarmed;
- EKF3's LOCAL_POSITION_NED against SITL's truth (SIM_STATE): RMS and max
  within issue 20's targets (3 cm, 10 cm);
- star's poses (its trajectory, at their capture times) against the
  truth: RMS within STAR_RMS_CM (measured 0.36-0.53 cm over the flights in
  docs/benchmarks.md; margin for SIM_STATE's 1.1 cm position steps), and
  no wrong pose (DESIGN.md: none more than STAR_MAX_CM off). The max is
  not held tighter: the truth is timed by the harness's Python thread, and
  at 0.5 m/s a 60 ms hiccup of it on a loaded machine is 3 cm (one flight
  measured 4.4 cm, the others 1.3-2.0 cm);
- EKF3 never stopped using external navigation;
- from arming to disarming EKF3 dropped no vision sample (its 20 ms rule
  replayed on its own log, `flight.ekf3_dropped`), with star set as the
  integration guide sets it for ArduPilot (`autopilot_min_interval_ms =
  25`: every other frame of the 50 Hz camera, 40 ms apart, so that neither
  star's `usec` nor ArduPilot's jitter correction, which moves a sample by
  up to one 2.5 ms step of SITL's loop, brings two under 20 ms). The whole
  log is reported, not asserted: on the ground, the stream's second sample
  can be dropped when the first reached SITL more than 20 ms later than it
  (one CI run: the first 27 ms, the second 4.5 ms after capture; the
  jitter correction then dates the second 17.5 ms after the first).
  `STAR_FLIGHT_LAPS=5`: the 2-minute flight of issue 20's target.

Reported, not asserted (they depend on the machine's load): the capture to
SITL delay of each VISION_POSITION_ESTIMATE (through the TCP tap) and the
VISO_DELAY_MS it implies, the tracker's losses, and the CPU use of each
process (from /proc/PID/stat). Figures: `pytest -s`. Skips without
`../shared/sitl/arducopter`.
"""

import math

import numpy as np

import flight
from sitl import SKIP

pytestmark = SKIP

EKF_RMS_CM = 3.0
EKF_MAX_CM = 10.0
STAR_RMS_CM = 1.5
STAR_MAX_CM = 10.0
CORNER_TOL_M = 0.3


def test_square_on_vision(star_bin, tmp_path):
    scene = flight.synth_scene(star_bin, tmp_path / "scene")
    record = flight.fly(star_bin, tmp_path / "flight", scene, viso_delay_ms=flight.VISO_DELAY_MS)
    f = flight.figures(record)
    track_log = open(record["track_log"]).read()
    # The localizer's lost test (not the start-up hint check before tracking).
    losses = track_log.count("star::localizer: tracking lost")
    print("\n" + flight.report(f) + f"\ntracker losses: {losses}")

    # The flight: every corner reached, landed at the start.
    origin = record["origin"]
    ph = record["phases"]
    path = np.array([flight.ned_of(origin, *v) for t, v in record["truth"] if ph["armed"] <= t <= ph["disarmed"]])
    s = flight.SQUARE_M
    for corner in [(0, 0), (s, 0), (s, s), (0, s)]:
        closest = min(math.dist(p[:2], corner) for p in path)
        assert closest <= CORNER_TOL_M, f"corner {corner} missed by {closest:.2f} m"
    assert min(p[2] for p in path) <= -0.9 * flight.ALT_M, "never reached the take-off height"
    assert abs(path[-1][2]) < 0.1 and math.dist(path[-1][:2], (0, 0)) < CORNER_TOL_M, f"landed at {path[-1]}"

    assert not [t for t in record["texts"] if "stopped aiding" in t], record["texts"]
    assert f["ekf_rms_cm"] <= EKF_RMS_CM and f["ekf_max_cm"] <= EKF_MAX_CM, flight.report(f)
    assert f["star_rms_cm"] <= STAR_RMS_CM and f["star_max_cm"] <= STAR_MAX_CM, flight.report(f)
    assert f["delay_matched"] > 0.5 * f["star_poses"], "VISION_POSITION_ESTIMATEs not matched to star's poses"
    assert f["visp"] > 0, "no VISP rows in SITL's log"
    assert f["visp_dropped_star_usec"] == 0, flight.report(f)
    assert f["visp_armed"] > 0, "no VISP rows between arming and disarming"
    assert f["visp_dropped_armed"] == 0, flight.report(f)
