"""How a recording's pairs are scored, as ../shared/tools/scoreboard
scores them: a pair next to a change of the truth (one either side) is a
grace pair and not scored; a frame with no row or a status other than ok
was not judged and counts as wrong; a raised alarm more than 10 % (at
least 50 mm) from the truth's `nearest_mm` is misplaced (listed, not
wrong). One home for the rule the analysis tools share."""

import csv
import io
import os
import tomllib


def truth_of(rec):
    """The recording's truth pairs by frame."""
    with open(os.path.join(rec, "truth.toml"), "rb") as f:
        return {p["frame"]: p for p in tomllib.load(f).get("pair", [])}


def rows_of(csv_text):
    """`flatland detect --format csv` output by frame."""
    return {int(row["frame"]): row for row in csv.DictReader(io.StringIO(csv_text))}


def scored(truth, frame):
    """Whether a pair is scored: not next to a change of the truth."""
    return not any(g in truth and truth[g]["alarm"] != truth[frame]["alarm"] for g in (frame - 1, frame + 1))


def is_judged(row):
    """Whether `flatland detect` judged the frame (a row with status ok)."""
    return row is not None and row.get("status", "ok") == "ok"


def raised(row):
    """Whether `flatland detect` judged the frame and raised the alarm."""
    return is_judged(row) and row["alarm"] == "1"


def misplaced(row, pair):
    """Whether a raised alarm lies more than 10 % (at least 50 mm) from the truth's nearest_mm."""
    if "nearest_mm" not in pair:
        return False
    try:
        near = float(row.get("nearest_mm", ""))
    except ValueError:
        return True
    return abs(near - pair["nearest_mm"]) > max(0.1 * pair["nearest_mm"], 50.0)


def score(truth, rows):
    """(scored pairs, right, false alarms, misses, not judged, misplaced) of one run."""
    counts = dict(pairs=0, right=0, false_alarms=0, misses=0, not_judged=0, misplaced=0)
    for frame, pair in truth.items():
        if not scored(truth, frame):
            continue
        counts["pairs"] += 1
        row = rows.get(frame)
        if not is_judged(row):
            counts["not_judged"] += 1
            continue
        alarm = raised(row)
        if alarm and not pair["alarm"]:
            counts["false_alarms"] += 1
        elif pair["alarm"] and not alarm:
            counts["misses"] += 1
        else:
            counts["right"] += 1
            counts["misplaced"] += int(alarm and misplaced(row, pair))
    return counts
