#!/usr/bin/env python3
"""Writes the MAVLink fuzz seeds, host-tests/fuzz/seeds/mavlink/, with
pymavlink: what an autopilot sends the firmware, packed by the reference
implementation rather than by our own encoder. host-tests/tests/
mavlink_interop.rs reads them back with core's decoder.

usage: mavlink_seeds.py [DIR]   (default: host-tests/fuzz/seeds/mavlink)

- odometry.bin: ODOMETRY (LOCAL_NED, body FRD) at 0, 0.1, 0.2 s: 100 mm
  north and 2 mm east per step, heading 1.5 degrees clockwise per step,
  level (roll and pitch variances 0: attitude given).
- local_position.bin: a HEARTBEAT, then ATTITUDE + LOCAL_POSITION_NED at
  0, 100, 200 ms: 100 mm north and 3 mm east per step, heading 2 degrees
  clockwise per step; rolled 0.01 rad (right side down) at the first,
  pitched -0.02 rad (nose down) at the second, level at the third.
"""

import math
import os
import sys

from pymavlink.dialects.v20 import common as m


class Link:
    """One sender: system 1, component 1, its sequence stepping by one."""

    def __init__(self):
        self.mav = m.MAVLink(None, srcSystem=1, srcComponent=1)

    def pack(self, message):
        frame = message.pack(self.mav)
        self.mav.seq = (self.mav.seq + 1) % 256
        return frame


def odometry():
    link = Link()
    covariance = [0.0] * 21
    frames = b""
    for i in range(3):
        half = math.radians(1.5 * i) / 2
        q = [math.cos(half), 0.0, 0.0, math.sin(half)]
        frames += link.pack(m.MAVLink_odometry_message(
            100000 * i, m.MAV_FRAME_LOCAL_NED, m.MAV_FRAME_BODY_FRD, 0.1 * i, 0.002 * i, 0.0, q,
            0.0, 0.0, 0.0, 0.0, 0.0, 0.0, covariance, covariance, 0, m.MAV_ESTIMATOR_TYPE_VIO, 100))
    return frames


def local_position():
    link = Link()
    frames = link.pack(m.MAVLink_heartbeat_message(
        m.MAV_TYPE_GROUND_ROVER, m.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, m.MAV_STATE_ACTIVE, 3))
    for i, (roll, pitch) in enumerate(((0.01, 0.0), (0.0, -0.02), (0.0, 0.0))):
        frames += link.pack(m.MAVLink_attitude_message(100 * i, roll, pitch, math.radians(2.0 * i), 0.0, 0.0, 0.0))
        frames += link.pack(m.MAVLink_local_position_ned_message(100 * i, 0.1 * i, 0.003 * i, 0.0, 0.0, 0.0, 0.0))
    return frames


def main(directory):
    os.makedirs(directory, exist_ok=True)
    for name, frames in (("odometry.bin", odometry()), ("local_position.bin", local_position())):
        with open(os.path.join(directory, name), "wb") as seed:
            seed.write(frames)


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else os.path.join(os.path.dirname(__file__), "..", "fuzz", "seeds", "mavlink"))
