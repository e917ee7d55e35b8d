"""``voxnero material``: stage 2 (materials and lights on the fixed mesh).

Not built yet (issue #4)."""

from __future__ import annotations

import argparse

from voxnero.cli import add_common
from voxnero.commands._notbuilt import not_built

NAME = "material"
HELP = "stage 2 (materials and lights on the fixed mesh) [not built yet]"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_common(parser, "scene folder or run folder", out_required=False)


def run(args: argparse.Namespace) -> int:
    return not_built(NAME, "issue #4")
