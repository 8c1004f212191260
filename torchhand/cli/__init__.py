"""The ``torchhand`` command line.

Each subcommand lives in its own module ``torchhand/cli/<name>_cmd.py`` exposing ``register(subparsers)``, which
adds its parser and sets ``func(args) -> int``. ``main`` turns every :class:`~torchhand.errors.TorchhandError`
into one line on stderr and exit code 2; a traceback means a bug.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys

from .._numerics import MODES, pin_for_command
from ..errors import TorchhandError
from ._common import apply_graph_setting

# Subcommand modules, in the order they appear in --help. A module that is not there yet is skipped.
_COMMANDS = ("scene", "hand", "inspect", "synthesize", "fill", "check", "render", "plot", "splice", "export", "view",
             "batch", "capture", "grasp", "manipulate", "numerics")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="torchhand",
        description="Physically plausible hand-motion synthesis on a batched PyTorch core.",
    )
    parser.add_argument("--version", action="version", version=_version())
    parser.add_argument("--numerics", choices=MODES, default=None,
                        help="numeric code paths: portable (default, or $TORCHHAND_NUMERICS: the same results on any "
                             "x86-64 CPU with AVX2) or native (the machine's fastest; results may differ between "
                             "CPUs). See `torchhand numerics`")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name in _COMMANDS:
        try:
            module = importlib.import_module(f".{name}_cmd", __name__)
        except ModuleNotFoundError as err:
            if err.name and err.name.endswith(f"{name}_cmd"):
                continue
            raise
        module.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    # Idle OpenMP threads sleep instead of spinning, so that a busy machine does not starve torch's thread pool
    # (read once, when torch loads: the subcommands import it below). See torchhand/cli/_common.py.
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    try:
        # Numeric code paths first: torch and NumPy read them when they load (torchhand/_numerics.py).
        pin_for_command(sys.argv[1:] if argv is None else argv)
        apply_graph_setting()
    except TorchhandError as err:
        print(f"torchhand: error: {err}", file=sys.stderr)
        return 2
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except TorchhandError as err:
        print(f"torchhand: error: {err}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # output piped into `head` and the like
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except KeyboardInterrupt:
        print("torchhand: interrupted", file=sys.stderr)
        return 130


def _version() -> str:
    from .. import __version__

    return f"torchhand {__version__}"


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
