#!/usr/bin/env python3
"""A pymavlink stand-in for the autopilot, for the MAVLink link tests.

It listens on a connection (e.g. udpin:127.0.0.1:14550), decodes every
message as MAVLink 2 with CRC checking (robust parsing: a bad frame becomes a
BAD_DATA record instead of being skipped silently), and plays the autopilot:
- a HEARTBEAT (quadrotor, PX4) once a second;
- TIMESYNC requests every --timesync-period seconds;
- answers to the link's TIMESYNC requests.

SIGTERM stops it early (the summary is still written).

Its clock is CLOCK_MONOTONIC + --clock-offset-ns, so the test can check that
the link estimates the offset and applies it to `usec`.

Output (--out): one JSON object per line:
- {"kind": "rx", "t_ns", "clock_ns", "type", "id", "sysid", "compid",
   "mavlink2", "fields"} for each message received (NaN floats as "NaN");
- {"kind": "timesync_request", "ts1"} for each request we sent;
- {"kind": "summary", "bad_data", "bad_reasons", "received", "v1"} at the end.
"ready" is printed on stdout once the socket is open.
"""

import argparse
import json
import math
import os
import signal
import sys
import time

os.environ["MAVLINK20"] = "1"
from pymavlink import mavutil  # noqa: E402

mavutil.set_dialect("common")


def clean(value):
    """JSON-safe copy: NaN/inf floats become strings, bytes become lists."""
    if isinstance(value, float) and not math.isfinite(value):
        return str(value) if not math.isnan(value) else "NaN"
    if isinstance(value, (list, tuple)):
        return [clean(v) for v in value]
    if isinstance(value, (bytes, bytearray)):
        return list(value)
    if isinstance(value, dict):
        return {k: clean(v) for k, v in value.items()}
    return value


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--listen", required=True, help="pymavlink connection string, e.g. udpin:127.0.0.1:14550")
    ap.add_argument("--duration", type=float, default=3.0, help="seconds to run")
    ap.add_argument("--clock-offset-ns", type=int, default=0, help="our clock = CLOCK_MONOTONIC + this")
    ap.add_argument("--timesync-period", type=float, default=0.25, help="seconds between our TIMESYNC requests; 0 = none")
    ap.add_argument("--answer-timesync", type=int, default=1, help="answer the link's TIMESYNC requests (1/0)")
    ap.add_argument("--sysid", type=int, default=1)
    ap.add_argument("--out", required=True, help="JSON-lines output file")
    args = ap.parse_args()

    def clock_ns():
        return time.monotonic_ns() + args.clock_offset_ns

    conn = mavutil.mavlink_connection(
        args.listen, source_system=args.sysid, source_component=1, robust_parsing=True, dialect="common"
    )
    print("ready", flush=True)

    # SIGTERM ends the run early but still writes the summary.
    stopped = []
    signal.signal(signal.SIGTERM, lambda *_: stopped.append(True))

    bad_data, bad_reasons, received, v1 = 0, [], 0, 0
    end = time.monotonic() + args.duration
    next_heartbeat = next_timesync = time.monotonic()
    with open(args.out, "w") as out:
        while time.monotonic() < end and not stopped:
            now = time.monotonic()
            # udpin learns its peers from what arrives (`clients` in current
            # pymavlink, `last_address` in older releases).
            peer_known = bool(getattr(conn, "clients", None)) or getattr(conn, "last_address", None) is not None
            if peer_known and now >= next_heartbeat:
                next_heartbeat = now + 1.0
                conn.mav.heartbeat_send(
                    mavutil.mavlink.MAV_TYPE_QUADROTOR, mavutil.mavlink.MAV_AUTOPILOT_PX4, 0, 0,
                    mavutil.mavlink.MAV_STATE_ACTIVE,
                )
            if peer_known and args.timesync_period > 0 and now >= next_timesync:
                next_timesync = now + args.timesync_period
                ts1 = clock_ns()
                conn.mav.timesync_send(0, ts1)
                out.write(json.dumps({"kind": "timesync_request", "ts1": ts1}) + "\n")

            msg = conn.recv_match(blocking=True, timeout=0.02)
            if msg is None:
                continue
            t_ns = time.monotonic_ns()
            mtype = msg.get_type()
            if mtype == "BAD_DATA":
                # Bytes that did not form a valid frame (bad CRC, bad magic).
                bad_data += 1
                bad_reasons.append(str(getattr(msg, "reason", "")))
                continue
            received += 1
            is_v2 = msg.get_msgbuf()[0] == 0xFD
            if not is_v2:
                v1 += 1
            if mtype == "TIMESYNC" and msg.tc1 == 0 and args.answer_timesync:
                conn.mav.timesync_send(clock_ns(), msg.ts1)
            record = {
                "kind": "rx",
                "t_ns": t_ns,
                "clock_ns": t_ns + args.clock_offset_ns,
                "type": mtype,
                "id": msg.get_msgId(),
                "sysid": msg.get_srcSystem(),
                "compid": msg.get_srcComponent(),
                "mavlink2": is_v2,
                "fields": clean(msg.to_dict()),
            }
            out.write(json.dumps(record) + "\n")
        out.write(json.dumps({
            "kind": "summary", "bad_data": bad_data, "bad_reasons": bad_reasons[:10],
            "received": received, "v1": v1,
        }) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
