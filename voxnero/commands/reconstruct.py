"""``voxnero reconstruct``: stage 1 then stage 2 with one preset.

Not built yet (issues #7 and #4)."""

from __future__ import annotations

import argparse

from voxnero.cli import add_common
from voxnero.commands._notbuilt import not_built

NAME = "reconstruct"
HELP = "stage 1 then stage 2 with one preset [not built yet]"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_common(parser, "scene folder or run folder", out_required=False)


def run(args: argparse.Namespace) -> int:
    return not_built(NAME, "issues #7 and #4")
