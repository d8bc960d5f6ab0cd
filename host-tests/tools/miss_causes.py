#!/usr/bin/env python3
"""Why the wrong pairs of rendered recordings are wrong: each miss sorted by
what the frame could tell, each false alarm by what raised it. The figures
behind a change of the decision or of the keyframe schedule, which the
scoreboard's right/wrong alone does not give.

usage: miss_causes.py FLATLAND SCENES_DIR REC [REC ...] [--odometry none]

FLATLAND is the `flatland` binary; SCENES_DIR the folder of the scene TOMLs
the recordings were rendered from (named like them, as random_scenes.py
writes them). The hazard a missed pair is about is the scene's nearest one
in the AOI at the frame's true pose (the renderer's own `pair_truth` rule:
obstacles 20 mm or higher, drops 20 mm or deeper). Pairs next to a change
of the truth are not scored, as on the scoreboard. Needs the renderer,
../shared/tools/render, and its Python environment (numpy).

A miss is, first that applies:
- `not judged`: the frame's status is not ok;
- `under a camera pixel since the start`: the hazard moves less than one
  camera pixel past the ground (as below) between this frame and every
  earlier one, at the renderer's true poses: no keyframe, however old,
  would give it a pixel (a robot that has stood still since the start
  shows nothing at all);
- `below resolution`: the hazard is lower (a drop: shallower) than the frame
  tells from the ground at its baseline (`least_height_mm`,
  `shallowest_drop_mm` of `flatland detect --cells`: docs/ARCHITECTURE.md,
  "How certain a height is"); unknown on a frame where no cell measured
  anything (the table lists none);
- `under a camera pixel`: over the frame's baseline T the hazard moves
  less than one camera pixel past the ground where it shows: an
  obstacle's top (h, at most the top hypothesis H/2) T h/(H-h) at
  p = z H/(H-h), a drop's lower level T d/(H+d) at its edge, against the
  camera's ground footprint per image row there, about (H^2 + p^2)/(H fy).
  The grid's least height counts grid pixels, but far in the AOI one
  camera pixel spans several: there the keyframe's baseline is too short
  for the camera, whatever the detector does with the cells;
- `nothing measured there`: no cell has a height, a lag or residue within a
  cell of where the hazard shows in the top view (an obstacle from its
  footprint to where its top is seen, H/(H-h) times as far from the camera,
  sideways too, inside the AOI or not; a drop from its edge to the AOI's
  far edge);
- `measured there, weakly`: cells there measured something, every one of
  them weakly (their best hypothesis beats the ground by less than the
  gain a height needs: low contrast), and no hazard was decided;
- `measured there`: some of them measured it firmly, and no hazard was
  decided (the groups' rules: size, residue, baseline);
- `unknown hazard`: the truth says alarm, but no hazard of the scene lies
  in the AOI by the renderer's rule (the two disagree; counted, unsorted).
Each miss is also counted by where the hazard starts in the AOI: `near`
(its first fifth), `far` (its last fifth) or `middle`. A clear pair
that is wrong is a false alarm `held` (a hazard of an earlier frame,
carried on) or `found` on the frame itself (`flatland detect --verbose`),
or `not judged`; and, by the truth around it, `early` (up to three frames
before a run of alarm pairs: the hazard not in the AOI yet, mostly just
beyond its far edge), `lingering` (up to three frames after one) or
`apart` (no hazard near in time). Last, the misses by hazard: each run
of consecutive alarm pairs of the truth is one hazard, `raised` on some
frame of it (its misses before the first alarm are `late`) or `never
raised`.

The last line is the ceiling those causes leave: the right pairs there
would be if every wrong pair were right but the misses the frames'
baselines cannot tell from the ground (the three causes above
`nothing measured there`): what a better decision alone could reach;
and but those no keyframe could (`under a camera pixel since the
start`): what any choice of keyframes could.

stdout: a line per recording with a wrong pair, then the totals and the
ceiling.
"""

import csv
import os
import subprocess
import sys
import tempfile
import tomllib
from collections import Counter, defaultdict

from pairs import is_judged, raised, rows_of, scored, truth_of
from rendered_set import arguments, scene_of  # also puts the renderer on the path
import generate  # noqa: E402  (the renderer's own poses and truth geometry)
import numpy as np  # noqa: E402
from rigmath import world_to_robot_xz  # noqa: E402

MISS_CAUSES = ("not judged", "under a camera pixel since the start", "below resolution", "under a camera pixel", "nothing measured there", "measured there, weakly", "measured there", "unknown hazard")
BANDS = ("near", "middle", "far")
ALARM_CAUSES = ("held", "found", "not judged")
TIMINGS = ("early", "lingering", "apart")
# The misses the frames' baselines cannot tell from the ground.
BASELINE_CAUSES = ("under a camera pixel since the start", "below resolution", "under a camera pixel")
# A false alarm this many frames or fewer before a hazard's first alarm
# pair is `early`, after its last one `lingering`: the decision's timing
# at the AOI's edges, not a hazard made up (`apart`).
TIMING_FRAMES = 3
GROUND_LIMIT_MM = 20.0


def nearest_hazards(sc):
    """Per frame (1..), the nearest hazard in the AOI at the true pose:
    (kind, height or depth mm, where it starts mm ahead, its (left, right)
    mm in the AOI, its whole footprint in the robot frame), or None."""
    a = sc["aoi"]
    hw, near, far = a["half_width_mm"], a["near_mm"], a["far_mm"]
    poses = generate.true_poses(sc)
    found = {}
    for i in range(1, len(poses)):
        t = i * sc["dt_s"]
        best = None
        for ob in sc["obstacle"]:
            if ob["height_mm"] >= GROUND_LIMIT_MM:
                fp = generate.footprint(ob, generate.obstacle_pos(ob, t))
                best = nearer(best, ("obstacle", ob["height_mm"]), fp, poses[i], (hw, near, far))
        for dr in sc["drop"]:
            if dr["drop_mm"] >= GROUND_LIMIT_MM:
                best = nearer(best, ("drop", dr["drop_mm"]), generate.drop_footprint(dr), poses[i], (hw, near, far))
        found[i] = best
    return found


def nearer(best, hazard, footprint, pose, aoi):
    hw, near, far = aoi
    xr, zr = world_to_robot_xz(footprint[:, 0], footprint[:, 1], pose)
    clipped = generate.clip_rect(np.stack([xr, zr], 1), -hw, hw, near, far)
    if not clipped:
        return best
    start = min(p[1] for p in clipped)
    across = (min(p[0] for p in clipped), max(p[0] for p in clipped))
    whole = np.stack([xr, zr], 1)
    return best if best is not None and best[2] <= start else (hazard[0], hazard[1], start, across, whole)


def detect(flatland, rec, extra):
    """The csv rows by frame, the frames' listed cells, and the --verbose sources."""
    with tempfile.TemporaryDirectory() as tmp:
        cells_path = os.path.join(tmp, "cells.csv")
        run = subprocess.run([flatland, "detect", rec, "--format", "csv", "--verbose", "--cells", cells_path, *extra],
                             capture_output=True, text=True, check=True)
        cells = defaultdict(list)
        with open(cells_path) as f:
            for row in csv.DictReader(f):
                cells[int(row["frame"])].append(row)
    rows = rows_of(run.stdout)
    sources = {}
    for line in run.stderr.splitlines():
        if line.startswith("frame ") and ": " in line:
            frame, source = line[len("frame "):].split(": ", 1)
            if frame.isdigit():
                sources[int(frame)] = source.strip()
    return rows, cells, sources


def miss_cause(row, cells, hazard, camera, aoi, cell_mm, longest_baseline_mm):
    if not is_judged(row):
        return "not judged"
    if pixels_moved(longest_baseline_mm, hazard, camera) < 1.0:
        return "under a camera pixel since the start"
    kind, size_mm = hazard[0], hazard[1]
    if cells:
        limit = float(cells[0]["least_height_mm" if kind == "obstacle" else "shallowest_drop_mm"] or "inf")
        if size_mm < limit:
            return "below resolution"
    if camera_pixels(row, hazard, camera) < 1.0:
        return "under a camera pixel"
    there = [c for c in cells if shows_there(c, hazard, camera[0], aoi, cell_mm)]
    if not there:
        return "nothing measured there"
    return "measured there" if any(c["weak"] == "0" for c in there) else "measured there, weakly"


def camera_pixels(row, hazard, camera):
    """How many camera pixels the hazard moves past the ground over the
    frame's baseline, where it shows (see the `under a camera pixel`
    cause); `camera` is (H, fy)."""
    return pixels_moved((float(row["tx_mm"] or 0.0) ** 2 + float(row["tz_mm"] or 0.0) ** 2) ** 0.5, hazard, camera)


def pixels_moved(baseline, hazard, camera):
    """Camera pixels the hazard moves past the ground over `baseline` mm
    of travel, where it shows (`camera_pixels`)."""
    height_mm, fy = camera
    kind, size_mm, start = hazard[0], hazard[1], hazard[2]
    if kind == "obstacle":
        top = min(size_mm, 0.5 * height_mm)
        seen_at, moved = start * height_mm / (height_mm - top), baseline * top / (height_mm - top)
    else:
        seen_at, moved = start, baseline * size_mm / (height_mm + size_mm)
    footprint = (height_mm ** 2 + seen_at ** 2) / (height_mm * fy)
    return moved / footprint


def shows_there(cell, hazard, camera_height_mm, aoi, cell_mm):
    """Whether a listed cell lies, within a cell, where the hazard shows in
    the top view. A drop: from its edge to the AOI's far edge, across its
    part of the AOI. An obstacle: a point of it h up shows H/(H-h) times as
    far from the camera (which stands over the robot origin in rendered
    rigs) as its footprint, ahead and sideways alike: a tall thing beside
    the AOI shows outside it, fanning out."""
    kind, size_mm, start, (left, right), footprint = hazard
    x, z = float(cell["x_mm"]), float(cell["z_mm"])
    if kind == "drop":
        return left - cell_mm <= x <= right + cell_mm and start - cell_mm <= z <= aoi["far_mm"] + cell_mm
    # The cell's point brought back toward the camera by every factor
    # (H-h)/H a height up to the obstacle's gives, against the footprint
    # grown by a cell.
    lowest = max(0.0, 1.0 - size_mm / camera_height_mm)
    (x0, z0), (x1, z1) = footprint.min(axis=0) - cell_mm, footprint.max(axis=0) + cell_mm
    for s in np.linspace(lowest, 1.0, 24):
        if x0 <= x * s <= x1 and z0 <= z * s <= z1:
            return True
    return False


def cell_size_mm(cells):
    """A cell's side (mm), from the spacing of the cell centres listed."""
    zs = sorted({float(c["z_mm"]) for frame in cells.values() for c in frame})
    steps = [b - a for a, b in zip(zs, zs[1:]) if b - a > 1.0]
    return min(steps) if steps else 0.0


def band(start_mm, aoi):
    fraction = (start_mm - aoi["near_mm"]) / (aoi["far_mm"] - aoi["near_mm"])
    return "near" if fraction < 0.2 else "far" if fraction > 0.8 else "middle"


def causes(flatland, scene, rec, extra):
    sc = generate.load_scene(scene)
    hazards = nearest_hazards(sc)
    with open(os.path.join(rec, "rig.toml"), "rb") as f:
        rig = tomllib.load(f)
    camera = (rig["mount"]["height_mm"], rig["camera"]["fy"])
    truth = truth_of(rec)
    rows, cells, sources = detect(flatland, rec, extra)
    cell_mm = cell_size_mm(cells)
    poses = generate.true_poses(sc)
    counts = Counter()
    for frame, pair in truth.items():
        if not scored(truth, frame):
            continue
        row = rows.get(frame)
        judged = is_judged(row)
        alarm = raised(row)
        counts["pairs", "scored"] += 1
        counts["pairs", "right"] += judged and alarm == pair["alarm"]
        if pair["alarm"] and not alarm:
            hazard = hazards.get(frame)
            if hazard is None:  # the truth's rule and ours disagree: count it, unsorted
                counts["miss", "unknown hazard"] += 1
                continue
            counts["miss", miss_cause(row, cells.get(frame, []), hazard, camera, sc["aoi"], cell_mm, longest_baseline_mm(poses, frame))] += 1
            counts["band", band(hazard[2], sc["aoi"])] += 1
        elif not pair["alarm"] and not judged:
            counts["alarm", "not judged"] += 1
        elif alarm and not pair["alarm"]:
            counts["alarm", "held" if sources.get(frame) == "Held" else "found"] += 1
            counts["timing", timing(truth, frame)] += 1
    counts.update(episodes(truth, rows))
    return counts


def longest_baseline_mm(poses, frame):
    """The longest travel (mm) between frame `frame`'s true pose and an
    earlier frame's: the baseline of the oldest keyframe it could have."""
    x, z = poses[frame][0], poses[frame][1]
    return max(((x - p[0]) ** 2 + (z - p[1]) ** 2) ** 0.5 for p in poses[:frame])


def timing(truth, frame):
    """Where a false alarm at `frame` lies against the truth's alarm pairs:
    `early` up to TIMING_FRAMES before the next, `lingering` up to that
    many after the last, else `apart`."""
    alarms = [f for f in truth if truth[f]["alarm"]]
    if any(0 < f - frame <= TIMING_FRAMES for f in alarms):
        return "early"
    if any(0 < frame - f <= TIMING_FRAMES for f in alarms):
        return "lingering"
    return "apart"


def episodes(truth, rows):
    """The hazards' episodes, each a run of consecutive alarm pairs of the
    truth: raised at all, or never; a raised one's scored misses before
    its first alarm (late) and after it. Tells a hazard found late from
    one never found, which a count of pairs mixes."""
    runs, run = [], []
    for frame in sorted(truth):
        if truth[frame]["alarm"] and run and run[-1] == frame - 1:
            run.append(frame)
        elif truth[frame]["alarm"]:
            run = [frame]
            runs.append(run)
    counts = Counter()
    for run in runs:
        alarms = [raised(rows.get(f)) for f in run]
        misses = [scored(truth, f) and not alarm for f, alarm in zip(run, alarms)]
        if True in alarms:
            first = alarms.index(True)
            counts["episode", "raised"] += 1
            counts["episode", "late pairs"] += sum(misses[:first])
            counts["episode", "missed after"] += sum(misses[first:])
        else:
            counts["episode", "never raised"] += 1
            counts["episode", "never raised pairs"] += sum(misses)
    return counts


def line(name, counts):
    misses = ", ".join("%s %d" % (c, counts["miss", c]) for c in MISS_CAUSES if counts["miss", c])
    bands = " / ".join(str(counts["band", b]) for b in BANDS)
    alarms = ", ".join("%s %d" % (c, counts["alarm", c]) for c in ALARM_CAUSES if counts["alarm", c])
    timings = ", ".join("%s %d" % (t, counts["timing", t]) for t in TIMINGS if counts["timing", t])
    if timings:
        alarms += " (%s)" % timings
    e = lambda key: counts["episode", key]
    hazards = "raised %d (late pairs %d, missed after %d), never raised %d (%d pairs)" % (
        e("raised"), e("late pairs"), e("missed after"), e("never raised"), e("never raised pairs"))
    return "%s | misses: %s | near/middle/far %s | clear pairs wrong: %s | hazards: %s" % (name, misses or "-", bands, alarms or "-", hazards)


def main(args):
    flatland, scenes, recs, extra = arguments(args, __doc__)
    total = Counter()
    for rec in recs:
        name, scene = scene_of(scenes, rec)
        counts = causes(flatland, scene, rec, extra)
        total.update(counts)
        if any(kind in ("miss", "alarm") for kind, _ in counts):
            print(line(name, counts))
    print(line("all", total))
    print(ceiling(total))


def ceiling(counts):
    """The line on the right pairs a better decision alone could reach."""
    scored = counts["pairs", "scored"]
    share = lambda pairs: "%d (%.1f %%)" % (pairs, 100.0 * pairs / max(scored, 1))
    limited = sum(counts["miss", cause] for cause in BASELINE_CAUSES)
    still = counts["miss", BASELINE_CAUSES[0]]
    return "ceiling | right %s of %d scored pairs; all but the %d misses the baselines cannot tell: %s; all but the %d no keyframe could: %s" % (
        share(counts["pairs", "right"]), scored, limited, share(scored - limited), still, share(scored - still))


if __name__ == "__main__":
    main(sys.argv[1:])
