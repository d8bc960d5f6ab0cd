#!/usr/bin/env python3
"""How far the measured motion is from the truth, on rendered recordings:
the check behind the estimator's changes, since an alarm's right or wrong
flips with a sub-millimetre change of the estimate and says little alone.

usage: motion_accuracy.py FLATLAND SCENES_DIR REC [REC ...] [--odometry none]

FLATLAND is the `flatland` binary; SCENES_DIR the folder of the scene TOMLs
the recordings were rendered from (named like them, as random_scenes.py
writes them). For every judged frame, `flatland detect`'s tx_mm, tz_mm and
dyaw_deg (keyframe -> frame) are compared with the scene's true poses,
which the renderer computes from its TOML (`generate.true_poses`: poses.csv
holds the odometry, with its errors). Needs the renderer,
../shared/tools/render, and its Python environment (numpy).

stdout: per recording the frames off by more than 20 / 50 / 100 mm and
by more than 1 / 3 degrees of yaw, then the totals.
"""

import csv
import io
import math
import subprocess
import sys

from rendered_set import arguments, scene_of  # also puts the renderer on the path
import generate  # noqa: E402  (the renderer's own poses)
from rigmath import relative  # noqa: E402

LIMITS_MM = (20, 50, 100)
LIMITS_DEG = (1, 3)


def errors(flatland, scene, rec, extra):
    """(translation error mm, yaw error deg) of every judged frame."""
    poses = generate.true_poses(generate.load_scene(scene))
    out = subprocess.run([flatland, "detect", rec, "--format", "csv", *extra],
                         capture_output=True, text=True, check=True).stdout
    found = []
    for row in csv.DictReader(io.StringIO(out)):
        if row.get("status", "ok") != "ok" or row["tx_mm"] == "":
            continue
        key, frame = int(row["ref_frame"]), int(row["frame"])
        tx, tz, dyaw = relative(poses[key], poses[frame])
        off_mm = math.hypot(float(row["tx_mm"]) - tx, float(row["tz_mm"]) - tz)
        found.append((off_mm, abs(float(row["dyaw_deg"]) - dyaw)))
    return found


def counts(found):
    return [sum(mm > limit for mm, _ in found) for limit in LIMITS_MM] + \
           [sum(deg > limit for _, deg in found) for limit in LIMITS_DEG]


def main(args):
    flatland, scenes, recs, extra = arguments(args, __doc__)
    header = "frames off by > %s mm, yaw off by > %s deg" % (" / ".join(map(str, LIMITS_MM)), " / ".join(map(str, LIMITS_DEG)))
    print("recording | frames | " + header)
    total, frames = [0] * (len(LIMITS_MM) + len(LIMITS_DEG)), 0
    for rec in recs:
        name, scene = scene_of(scenes, rec)
        found = errors(flatland, scene, rec, extra)
        row = counts(found)
        frames += len(found)
        total = [a + b for a, b in zip(total, row)]
        print("%s | %d | %s" % (name, len(found), " / ".join(map(str, row))))
    print("all | %d | %s" % (frames, " / ".join(map(str, total))))


if __name__ == "__main__":
    main(sys.argv[1:])
