"""star on a serial link to ArduPilot SITL (issue 20).

A `socat` pty pair stands in for the UART: SITL's SERIAL1 is one end
(`--serial1 uart:/dev/pts/N:921600`), star's `serial:` connection the other
(921600 baud). The test is the GCS on SERIAL0 as in `test_sitl.py`.
Nothing sits between star and SITL, so the figures come from SITL's own
dataflash log: EKF3's "is using external nav data" (MSG) must come within
FUSE_WITHIN_S of the first vision sample SITL received (VISP), and the EKF's
LOCAL_POSITION_NED must end within POSITION_TOL_M of the last one.

Skips without the SITL binary or without `socat` (`apt-get install socat`;
`scripts/setup.sh` installs it).
"""

import math
import time

import pytest

from conftest import Rig, write_subset
from sitl import SKIP, SOCAT, Gcs, PtyPair, Sitl, dataflash, free_instance, stop_all

pytestmark = [
    SKIP,
    pytest.mark.skipif(SOCAT is None, reason="socat not installed (apt-get install socat, or scripts/setup.sh); "
                       "serial SITL test skipped"),
]

BAUD = 921600
STILL_FRAMES = 300
FUSE_WITHIN_S = 1.0
POSITION_TOL_M = 0.01


@pytest.fixture(scope="module")
def still(dataset, tmp_path_factory):
    return write_subset(dataset, tmp_path_factory.mktemp("still") / "still", [0] * STILL_FRAMES)


def test_serial_link_fused(star_bin, still, tmp_path):
    pty = PtyPair(tmp_path)
    sitl = Sitl(free_instance(), tmp_path / "sitl", serial1=f"uart:{pty.a}:{BAUD}")
    gcs = None
    rig = Rig(star_bin, tmp_path, still)
    try:
        gcs = Gcs(sitl.gcs_port)
        gcs.start_streams()
        gcs.wait_text("EKF3 IMU0 tilt alignment complete", 40)
        run = rig.spawn(["run", "--config", str(rig.config), "--source", f"replay:{still}",
                         "--mavlink", f"serial:{pty.b}:{BAUD}", "--idle-exit-s", "1"], "run")
        run.communicate(timeout=STILL_FRAMES / 50 + 60)
        assert run.returncode == 0, run.log_path.read_text()[-3000:]
        run_end = time.monotonic()
        time.sleep(0.3)
    finally:
        stop_all(sitl, rig, gcs)
        pty.close()

    visp, msgs = dataflash(sitl.dir)
    assert len(visp) > 0.8 * STILL_FRAMES, f"SITL logged {len(visp)} vision samples over the serial link"
    first_us = visp[0][0]
    fused = [t for t, text in msgs if "EKF3 IMU0 is using external nav data" in text and t >= first_us]
    assert fused, f"EKF3 never used external nav: {[x for _, x in msgs]}"
    fused_after_s = (fused[0] - first_us) / 1e6
    fallbacks = [x for t, x in msgs if t > fused[0] and "stopped aiding" in x]
    last = visp[-1][1]
    window = [p for t, p in gcs.positions if run_end - 2.5 <= t <= run_end - 0.5]
    assert window, "no LOCAL_POSITION_NED in the last seconds of the run"
    position_err = max(math.dist(p, last) for p in window)
    spacing = [(b[0] - a[0]) / 1e3 for a, b in zip(visp, visp[1:])]
    print(f"\nserial {BAUD} baud via socat ({pty.a} <-> {pty.b}): {len(visp)} vision samples, EKF3 used external "
          f"nav {fused_after_s:.3f} s after the first, fallbacks {fallbacks}, EKF position "
          f"{position_err * 100:.2f} cm from the last sample, sample spacing at SITL median "
          f"{sorted(spacing)[len(spacing) // 2]:.1f} ms, max {max(spacing):.1f} ms")
    assert fused_after_s <= FUSE_WITHIN_S, f"fused {fused_after_s:.2f} s after the first vision sample"
    assert not fallbacks, fallbacks
    assert position_err <= POSITION_TOL_M, f"EKF position {position_err * 100:.2f} cm from star's"
