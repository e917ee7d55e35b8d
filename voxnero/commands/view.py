"""``voxnero view``: Open3D viewer of an asset. Not built yet (issue #5)."""

from __future__ import annotations

import argparse

from voxnero.cli import add_common
from voxnero.commands._notbuilt import not_built

NAME = "view"
HELP = "Open3D viewer of an asset [not built yet]"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_common(parser, "scene folder or run folder", out_required=False)


def run(args: argparse.Namespace) -> int:
    return not_built(NAME, "issue #5")
