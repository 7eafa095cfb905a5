"""The ``mer`` command: one thin parser per job, each calling one library function.

One module per command: :mod:`.robots` (``mer robots``), :mod:`.shards` (``mer shards``; ``solve``
is :mod:`.solve`), :mod:`.train`, :mod:`.finetune`, :mod:`.retarget`, :mod:`.evaluate`, :mod:`.zoo`,
:mod:`.demo` (with :mod:`.demo_walk`), :mod:`.view` (``mer view``). Each parses, resolves names once, and calls the library.
"""

from __future__ import annotations

import argparse
import logging
import os
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
from . import view as view_cli
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
    view_cli.add_parser(sub)
    for parser in _parsers(p):  # `--robot` is not silently `--robots`
        parser.allow_abbrev = False
    return p


def _parsers(p: argparse.ArgumentParser) -> list[argparse.ArgumentParser]:
    """``p`` and every subcommand's parser below it."""
    out = [p]
    for action in p._actions:
        if isinstance(action, argparse._SubParsersAction):
            for child in dict.fromkeys(action.choices.values()):
                out += _parsers(child)
    return out


def _command_parser(p: argparse.ArgumentParser, argv: Sequence[str]) -> argparse.ArgumentParser:
    """The deepest subcommand parser ``argv`` names (``mer shards solve`` → solve's)."""
    for action in p._actions:
        if isinstance(action, argparse._SubParsersAction):
            for i, word in enumerate(argv):
                if word in action.choices:
                    return _command_parser(action.choices[word], argv[i + 1 :])
    return p


def _unknown(parser: argparse.ArgumentParser, extra: list[str]) -> None:
    """Refuse unknown arguments with the subcommand's own usage and the nearest option names."""
    from mer_data.base.suggest import close_matches

    known = [o for a in parser._actions for o in a.option_strings]
    hints = []
    for word in extra:
        if word.startswith("-"):
            near = close_matches(word.split("=", 1)[0], known)
            if near:
                hints.append(f"{word}: did you mean {' or '.join(near)}?")
    parser.error(f"unrecognized arguments: {' '.join(extra)}" + ("; " + "; ".join(hints) if hints else ""))


#: Options naming an output FILE (every command's); ``--out`` names a folder unless its metavar is FILE.
_FILE_OUTPUTS = ("output", "npz", "mcap", "plot", "video")


def _check_outputs(command: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """Refuse unwritable outputs before the job runs (a read-only folder, a file where a folder is
    wanted): :func:`~mer_data.base.outputs.check_output_dir` / ``check_output_file``."""
    from mer_data.base.outputs import check_output_dir, check_output_file

    for name in _FILE_OUTPUTS:
        value = getattr(args, name, None)
        if isinstance(value, str) and value and value != "-":
            check_output_file(value, f"--{name}")
    out = getattr(args, "out", None)
    if isinstance(out, str) and out and not out.startswith("hf://"):
        as_file = any(a.dest == "out" and a.metavar == "FILE" for a in command._actions)
        (check_output_file if as_file else check_output_dir)(out, "--out")
    if getattr(args, "command", None) == "robots" and getattr(args, "robots_cmd", None) == "export" and getattr(args, "mjcf", None):
        check_output_file(args.mjcf, "--mjcf")  # --mjlab DIR: checked by the export itself
    if getattr(args, "command", None) == "robots" and getattr(args, "robots_cmd", None) == "register" and not getattr(args, "dry_run", False):
        from mer_data.robots.location import robots_dir

        check_output_dir(robots_dir(), "the robot registry (MER_HOME)")


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; returns the exit status (0 ok, 1 refused input, 2 usage, 130 interrupted)."""
    # torch's OpenMP threads spin while they wait; on a shared machine (or beside --workers) they
    # starve each other (300 frames G1 -> H1: 4.8-23 s spinning, 0.5 s passive, at load 5 on 2
    # cores). It takes effect only before torch's OpenMP runtime starts: here, before any import of torch.
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    parser = build_parser()
    argv = list(sys.argv[1:] if argv is None else argv)
    command = _command_parser(parser, argv)
    known = {o for a in (*command._actions, *parser._actions) for o in a.option_strings}
    typos = [w for w in argv if w.startswith("--") and w != "--" and w.split("=", 1)[0] not in known]
    if typos and command is not parser:  # before argparse complains about a required option the typo meant
        _unknown(command, typos)
    args, extra = parser.parse_known_args(argv)
    if extra:
        _unknown(command, extra)
    level = logging.WARNING - 10 * min(args.verbose, 2)
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")
    for noisy in ("yourdfpy", "trimesh", "urllib3", "httpx", "filelock"):
        logging.getLogger(noisy).setLevel(max(level, logging.ERROR))
    try:
        _check_outputs(command, args)
        return int(args.func(args) or 0)
    except MerError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # `mer robots list | head`
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except OSError as exc:  # a write the checks could not foresee (a folder made read-only meanwhile)
        from mer_data.base.outputs import os_refusal

        refused = os_refusal(exc, exc.filename or "")
        if refused is None:
            raise
        print(f"error: {refused}", file=sys.stderr)
        return 1

