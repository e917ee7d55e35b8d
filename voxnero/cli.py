"""The ``voxnero`` command line.

Every command follows one calling convention::

    voxnero <command> SCENE_OR_RUN --preset NAME --out DIR [key=value ...]

Each command lives in its own module under :mod:`voxnero.commands` exposing ``NAME``, ``HELP``,
``add_arguments(parser)`` and ``run(args) -> int``; this file only discovers and dispatches them.
User errors (:class:`voxnero.errors.VoxneroError`) print one or two lines and exit with code 2;
``--debug`` shows the traceback.
"""

from __future__ import annotations

import argparse
import importlib
import re
import sys

from voxnero.errors import VoxneroError

COMMANDS = ["synth", "shape", "material", "reconstruct", "relight", "eval", "view", "info",
            "batch", "demo"]
"""Command modules, in the order ``--help`` lists them."""


def add_common(parser: argparse.ArgumentParser, target_help: str, default_preset: str = "standard",
               out_required: bool = True) -> None:
    """Add the shared arguments: TARGET, ``--preset``, ``--out``, ``--device`` and overrides."""
    parser.add_argument("target", metavar="SCENE_OR_RUN", help=target_help)
    parser.add_argument("--preset", default=default_preset,
                        help=f"preset name (voxnero/configs/NAME.yaml) or a YAML path "
                             f"(default: {default_preset})")
    parser.add_argument("--out", required=out_required, help="output folder")
    parser.add_argument("--device", default="auto", help="auto (CUDA if available), cpu or cuda")
    parser.add_argument("overrides", nargs="*", metavar="key=value",
                        help="config overrides, e.g. iters=2000 grid.res=96")


def add_fresh(parser: argparse.ArgumentParser) -> None:
    """Add ``--fresh``: start over in ``--out`` instead of resuming its checkpoint."""
    parser.add_argument("--fresh", action="store_true",
                        help="start over: delete the checkpoint and run state in --out first "
                             "(its outputs are replaced only when the new run succeeds)")


def build_parser() -> argparse.ArgumentParser:
    """The top-level parser with one sub-parser per command module."""
    parser = argparse.ArgumentParser(
        prog="voxnero",
        description="Posed photos of a shiny object -> relightable mesh, BRDF and environment "
                    "light (explicit-voxel NeRO).",
        epilog="Every command: voxnero <command> SCENE_OR_RUN --preset NAME --out DIR "
               "[key=value ...]. Run 'voxnero <command> --help' for details.")
    parser.add_argument("--debug", action="store_true", help="show tracebacks of errors")
    sub = parser.add_subparsers(dest="command", metavar="<command>")
    for name in COMMANDS:
        mod = importlib.import_module(f"voxnero.commands.{name}")
        p = sub.add_parser(mod.NAME, help=mod.HELP,
                           description=getattr(mod, "DESCRIPTION", mod.HELP))
        p.add_argument("--debug", action="store_true", default=argparse.SUPPRESS,
                       help="show tracebacks of errors")
        mod.add_arguments(p)
        p.set_defaults(_run=mod.run)
    return parser


_OVERRIDE = re.compile(r"^[A-Za-z_][\w.]*=")


def parse_command_line(parser: argparse.ArgumentParser,
                       argv: list[str] | None) -> argparse.Namespace:
    """Parse ``argv``, accepting ``key=value`` overrides anywhere after the command.

    argparse alone stops filling the ``overrides`` positional once an option such as ``--out DIR``
    follows it, so the documented order ``SCENE --out DIR key=value`` would be refused; tokens left
    over that look like ``key=value`` are appended to ``args.overrides`` instead.
    """
    args, extras = parser.parse_known_args(argv)
    rest = [t for t in extras if not _OVERRIDE.match(t)]
    if rest:
        parser.error(f"unrecognized arguments: {' '.join(rest)}")
    overrides = [t for t in extras if _OVERRIDE.match(t)]
    if overrides:
        if not hasattr(args, "overrides"):
            parser.error(f"'{args.command}' takes no key=value overrides: {' '.join(overrides)}")
        args.overrides = list(args.overrides or []) + overrides
    return args


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``voxnero`` console script; returns the exit code."""
    parser = build_parser()
    args = parse_command_line(parser, argv)
    if not getattr(args, "command", None):
        parser.print_help()
        return 2
    try:
        return int(args._run(args) or 0)
    except VoxneroError as e:
        if getattr(args, "debug", False):
            raise
        print(f"voxnero {args.command}: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"\nvoxnero {args.command}: interrupted (checkpoints, if any, are kept)",
              file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
