#!/usr/bin/env python3
"""The scoreboard's noise floor: each set scored as it is and again under
sensor noise too faint to see (`flatland detect --perturb noise=SIGMA,
seed=K`, SIGMA 0.2 gray levels by default), so that a change is judged
by its mean over the runs, not by one run. A decision near a threshold
flips on such noise (and, through what a frame hands on, frames after
it): one run of a set of rendered recordings moves by several pairs
either way, and a change kept only where one run happens to gain
keeps that luck.

usage: noise_floor.py FLATLAND [--base FLATLAND] [--seeds K] [--noise SIGMA] [--odometry none] NAME=DIR ...

DIR is a recording (holding truth.toml) or a folder of recordings. Per
set: the right pairs of the plain run, of each noisy run, their mean
and range, and the same for false alarms and misplaced alarms; pairs
are scored as the scoreboard scores them (pairs.py). With `--base`, a
build without the change: each set is scored by both, and a `change`
line per set (and one for all sets) gives the new build's plain run and
means less the base's, the figures a change is judged by.
"""

import os
import statistics
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor

from pairs import rows_of, score, truth_of


def recordings(folder):
    """The recording `folder` is, or the recordings in it."""
    if os.path.exists(os.path.join(folder, "truth.toml")):
        return [folder]
    return [os.path.join(folder, name) for name in sorted(os.listdir(folder)) if os.path.exists(os.path.join(folder, name, "truth.toml"))]


def run(flatland, rec, extra, perturb):
    """One run's counts on one recording (perturbed when `perturb` is given)."""
    args = [flatland, "detect", rec, "--format", "csv", *extra] + (["--perturb", perturb] if perturb else [])
    done = subprocess.run(args, capture_output=True, text=True)
    return score(truth_of(rec), rows_of(done.stdout) if done.returncode == 0 else {})


def parse(args):
    """(flatland, base flatland or None, seeds, noise, extra detect arguments, [(name, dir)])."""
    args = list(args)
    options = {"--seeds": "4", "--noise": "0.2", "--odometry": None, "--base": None}
    for option in options:
        if option in args:
            at = args.index(option)
            options[option] = args[at + 1]
            del args[at:at + 2]
    if len(args) < 2 or not all("=" in a for a in args[1:]):
        sys.exit(__doc__)
    extra = ["--odometry", options["--odometry"]] if options["--odometry"] else []
    sets = [tuple(a.split("=", 1)) for a in args[1:]]
    return args[0], options["--base"], int(options["--seeds"]), options["--noise"], extra, sets


def totals_of(flatland, recs, extra, perturbs):
    """Per run (the plain one first), the counts summed over `recs`."""
    jobs = [(rec, perturb) for perturb in perturbs for rec in recs]
    with ThreadPoolExecutor(os.cpu_count() or 1) as pool:
        counts = list(pool.map(lambda job: run(flatland, job[0], extra, job[1]), jobs))
    totals = []
    for k in range(len(perturbs)):
        runs = counts[k * len(recs):(k + 1) * len(recs)]
        totals.append({key: sum(c[key] for c in runs) for key in runs[0]})
    return totals


def line(name, totals):
    """One build's figures on one set."""
    noisy = totals[1:]

    def spread(key):
        values = [t[key] for t in noisy]
        return "%s, mean %.1f, range %d-%d" % (" ".join(str(v) for v in values), statistics.mean(values), min(values), max(values)) if values else "-"

    return "%s: %d pairs | right: plain %d | noisy %s | false alarms: plain %d | noisy %s | misplaced: plain %d | noisy %s" % (
        name, totals[0]["pairs"], totals[0]["right"], spread("right"), totals[0]["false_alarms"], spread("false_alarms"),
        totals[0]["misplaced"], spread("misplaced"))


def change(name, base, new):
    """The new build's plain run and noisy means less the base's."""
    def mean(totals, key):
        return statistics.mean(t[key] for t in totals[1:]) if len(totals) > 1 else float("nan")

    parts = ["%s plain %+d, noisy mean %+.1f" % (label, new[0][key] - base[0][key], mean(new, key) - mean(base, key))
             for label, key in (("right", "right"), ("false alarms", "false_alarms"), ("misplaced", "misplaced"))]
    return "%s change: %s" % (name, " | ".join(parts))


def summed(per_set):
    """Each run's counts summed over the sets."""
    return [{key: sum(totals[k][key] for totals in per_set) for key in per_set[0][k]} for k in range(len(per_set[0]))]


def main(args):
    flatland, base, seeds, noise, extra, sets = parse(args)
    perturbs = [None] + ["noise=%s,seed=%d" % (noise, seed) for seed in range(1, seeds + 1)]
    scored = []
    for name, folder in sets:
        recs = recordings(folder)
        if not recs:
            print("%s: no recordings" % name)
            continue
        new = totals_of(flatland, recs, extra, perturbs)
        if base is None:
            print(line(name, new))
            continue
        old = totals_of(base, recs, extra, perturbs)
        print(line(name + " (base)", old))
        print(line(name, new))
        print(change(name, old, new))
        scored.append((old, new))
    if len(scored) > 1:
        print(change("all sets", summed([old for old, _ in scored]), summed([new for _, new in scored])))


if __name__ == "__main__":
    main(sys.argv[1:])
