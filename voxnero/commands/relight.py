"""``voxnero relight``: render an asset under another HDR environment map.

Not built yet (issue #5)."""

from __future__ import annotations

import argparse

from voxnero.cli import add_common
from voxnero.commands._notbuilt import not_built

NAME = "relight"
HELP = "render an asset under another HDR environment map [not built yet]"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_common(parser, "scene folder or run folder", out_required=False)


def run(args: argparse.Namespace) -> int:
    return not_built(NAME, "issue #5")
