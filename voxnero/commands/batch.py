"""``voxnero batch``: reconstruct many scenes on Ray. Not built yet (issue #9)."""

from __future__ import annotations

import argparse

from voxnero.cli import add_common
from voxnero.commands._notbuilt import not_built

NAME = "batch"
HELP = "reconstruct many scenes on Ray [not built yet]"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_common(parser, "scene folder or run folder", out_required=False)


def run(args: argparse.Namespace) -> int:
    return not_built(NAME, "issue #9")
