"""The command line the rendered-set tools share:
`TOOL FLATLAND SCENES_DIR REC [REC ...] [--odometry none]`, and the
renderer they read the truth from (../shared/tools/render)."""

import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
RENDER = os.path.normpath(os.path.join(HERE, "..", "..", "..", "shared", "tools", "render"))
sys.path.insert(0, RENDER)


def arguments(args, usage):
    """(flatland, scenes_dir, recordings, extra detect arguments) from
    `args`; exits with `usage` when they are too few."""
    args = list(args)
    extra = []
    if "--odometry" in args:
        at = args.index("--odometry")
        extra = args[at:at + 2]
        del args[at:at + 2]
    if len(args) < 3:
        sys.exit(usage)
    return args[0], args[1], args[2:], extra


def scene_of(scenes, rec):
    """The recording's name and the scene TOML it was rendered from."""
    name = os.path.basename(os.path.normpath(rec))
    return name, os.path.join(scenes, name + ".toml")
