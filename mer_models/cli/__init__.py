"""The ``mer`` command: one thin parser per job, each calling one library function.

One module per command: :mod:`.robots` (``mer robots``), :mod:`.shards` (``mer shards``; ``solve``
is :mod:`.solve`), :mod:`.train`, :mod:`.finetune`, :mod:`.retarget`, :mod:`.evaluate`, :mod:`.zoo`,
:mod:`.demo` (with :mod:`.demo_walk`). Each parses, resolves names once, and calls the library.
"""

from __future__ import annotations

import argparse
import logging
import sys
from typing import Sequence

from mer_data.base.errors import MerError
from mer_models import __version__

from . import demo as demo_cli
from . import evaluate as evaluate_cli
from . import finetune as finetune_cli
from . import retarget as retarget_cli
from . import robots as robots_cli
from . import shards as shards_cli
from . import solve as solve_cli
from . import train as train_cli
from . import zoo as zoo_cli

log = logging.getLogger("mer")


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="mer", description="Multi-embodiment robot motion retargeting: robots, shards, models."
    )
    p.add_argument("--version", action="version", version=f"mer {__version__}")
    p.add_argument("-v", "--verbose", action="count", default=0, help="more logging (-vv for debug)")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")
    robots_cli.add_parser(sub)
    solve_cli.add_parser(shards_cli.add_parser(sub))
    demo_cli.add_parser(sub)
    train_cli.add_parser(sub)
    finetune_cli.add_parser(sub)
    retarget_cli.add_parser(sub)
    evaluate_cli.add_parser(sub)
    zoo_cli.add_parser(sub)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; returns the exit status (0 ok, 1 refused input, 2 usage, 130 interrupted)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    level = logging.WARNING - 10 * min(args.verbose, 2)
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")
    for noisy in ("yourdfpy", "trimesh", "urllib3", "httpx", "filelock"):
        logging.getLogger(noisy).setLevel(max(level, logging.ERROR))
    try:
        return int(args.func(args) or 0)
    except MerError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # `mer robots list | head`
        import os

        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0

