"""`tofcut sweep --family NAME --seeds A-B --set tracker.PARAM=V1,V2,...`: the tracker on a
family of lines under every setting of a grid (several `--set` make it), and a table of
what it scores under each (`tofcut.tools.evaluation.sweep`)."""

from __future__ import annotations

import argparse

from tofcut.tools.commands.arguments import output_file
from tofcut.tools.evaluation import family, sweep
from tofcut.tools.evaluation.scoring import GATE_M, MIN_IOU, MIN_PIXELS
from tofcut.tools.pipeline.settings import setting
from tofcut.tools.pipeline.sources import SourceError


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "sweep", help="score the tracker on a family of lines under every setting of a grid"
    )
    p.add_argument(
        "--set", type=setting, action="append", required=True,
        metavar="tracker.PARAM=V1,V2,...",
        help="a tracker parameter and its values (tofcut.tracker.params.TrackerParams, e.g. "
        "tracker.beta=2,2.5,3 or tracker.background.rate=0.01,0.02); several make a grid",
    )  # fmt: skip
    p.add_argument("--json", type=output_file, help="also write the JSON document here")
    family.add_family_options(p, "the family of lines", trackers=False)
    p.set_defaults(func=run, gate=GATE_M, min_pixels=MIN_PIXELS, min_iou=MIN_IOU)


def run(args: argparse.Namespace) -> int:
    if not family.wants_family(args):
        raise SourceError("sweep needs --family NAME (or --scene PATTERN) and --seeds")
    return sweep.run(args)
