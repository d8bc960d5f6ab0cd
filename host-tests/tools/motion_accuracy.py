#!/usr/bin/env python3
"""How far the measured motion is from the truth: the check behind the
estimator's changes, since an alarm's right or wrong flips with a
sub-millimetre change of the estimate and says little alone.

usage: motion_accuracy.py FLATLAND SCENES_DIR REC [REC ...] [--odometry none]
       motion_accuracy.py FLATLAND --poses REC [REC ...] [--odometry none]

FLATLAND is the `flatland` binary; SCENES_DIR the folder of the scene TOMLs
the recordings were rendered from (named like them, as random_scenes.py
writes them). For every judged frame, `flatland detect`'s tx_mm, tz_mm and
dyaw_deg (keyframe -> frame) are compared with the scene's true poses,
which the renderer computes from its TOML (`generate.true_poses`: poses.csv
holds the odometry, with its errors). Needs the renderer,
../shared/tools/render, and its Python environment (numpy).

With `--poses` instead of SCENES_DIR the truth is each recording's own
poses.csv: for real recordings whose poses are measured by other means
(lidar odometry, GPS/INS; their READMEs say which), never for rendered
ones, whose poses.csv carries the odometry's errors.

stdout: per recording the frames off by more than 20 / 50 / 100 mm and
by more than 1 / 3 degrees of yaw, and the median of the travel's
relative error (measured over true travel, minus 1: negative when the
motion is measured short), then the totals.
"""

import csv
import io
import math
import os
import subprocess
import sys

from rendered_set import arguments, scene_of  # also puts the renderer on the path
import generate  # noqa: E402  (the renderer's own poses)
from rigmath import relative  # noqa: E402

LIMITS_MM = (20, 50, 100)
LIMITS_DEG = (1, 3)


# Travel shorter than this is left out of the relative error (standing still).
MIN_TRAVEL_MM = 10.0


def recorded_poses(rec):
    """The recording's poses.csv: (x mm, z mm, yaw deg) by frame."""
    with open(os.path.join(rec, "poses.csv")) as f:
        return {int(row["frame"]): (float(row["x_mm"]), float(row["z_mm"]), float(row["yaw_deg"]))
                for row in csv.DictReader(f) if row.get("x_mm", "") != ""}


def errors(flatland, poses, rec, extra):
    """(translation error mm, yaw error deg, relative travel error or None)
    of every judged frame, against `poses` (by frame)."""
    out = subprocess.run([flatland, "detect", rec, "--format", "csv", *extra],
                         capture_output=True, text=True, check=True).stdout
    found = []
    for row in csv.DictReader(io.StringIO(out)):
        if row.get("status", "ok") != "ok" or row["tx_mm"] == "":
            continue
        key, frame = int(row["ref_frame"]), int(row["frame"])
        if key not in poses or frame not in poses:
            continue
        tx, tz, dyaw = relative(poses[key], poses[frame])
        measured = (float(row["tx_mm"]), float(row["tz_mm"]))
        off_mm = math.hypot(measured[0] - tx, measured[1] - tz)
        travel = math.hypot(tx, tz)
        relative_travel = math.hypot(*measured) / travel - 1.0 if travel >= MIN_TRAVEL_MM else None
        found.append((off_mm, abs(float(row["dyaw_deg"]) - dyaw), relative_travel))
    return found


def counts(found):
    return [sum(mm > limit for mm, _, _ in found) for limit in LIMITS_MM] + \
           [sum(deg > limit for _, deg, _ in found) for limit in LIMITS_DEG]


def median_travel_error(found):
    values = sorted(r for _, _, r in found if r is not None)
    return "%+.1f %%" % (100.0 * values[len(values) // 2]) if values else "-"


def main(args):
    args = list(args)
    from_poses = "--poses" in args
    if from_poses:
        args.remove("--poses")
        args.insert(1, "")  # the shared parser's SCENES_DIR, unused
    flatland, scenes, recs, extra = arguments(args, __doc__)
    header = "frames off by > %s mm, yaw off by > %s deg | median travel error" % (" / ".join(map(str, LIMITS_MM)), " / ".join(map(str, LIMITS_DEG)))
    print("recording | frames | " + header)
    total, everything = [0] * (len(LIMITS_MM) + len(LIMITS_DEG)), []
    for rec in recs:
        name, scene = scene_of(scenes, rec)
        poses = recorded_poses(rec) if from_poses else dict(enumerate(generate.true_poses(generate.load_scene(scene))))
        found = errors(flatland, poses, rec, extra)
        row = counts(found)
        everything += found
        total = [a + b for a, b in zip(total, row)]
        print("%s | %d | %s | %s" % (name, len(found), " / ".join(map(str, row)), median_travel_error(found)))
    print("all | %d | %s | %s" % (len(everything), " / ".join(map(str, total)), median_travel_error(everything)))


if __name__ == "__main__":
    main(sys.argv[1:])
