"""The `ratouch` command line: a thin client of the library.

Every subcommand is `main(argv)`-callable. User errors print one line and exit with code 2,
and leave nothing half-written behind.

`parser.py` declares every command and its arguments, and names the module of this package
that runs it (`world`, `corpus`, `train`, `query`, `eval`, `experiments`, `bench`, `judge`,
`app`; each has `run(args)`). `main` imports that module only when its command runs, in one
place (`_run`): the command modules import the library's model side at their top (torch, faiss
and transformers, about 2-3 s), which `ratouch --help`, a usage error or `ratouch judge` should
not pay. The library itself imports at module top.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
from typing import Sequence

from ratouch.cli.parser import build_parser
from ratouch.errors import RATouchError

__all__ = ["build_parser", "main"]


def _run(args: argparse.Namespace) -> int:
    """Run a parsed command: import the module the parser named for it, call its `run`."""
    return importlib.import_module(f"{__name__}.{args.module}").run(args)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point. Returns the exit code (0 ok, 2 user error)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    try:
        return _run(args)
    except (RATouchError, OSError) as e:
        print(f"ratouch: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("ratouch: interrupted", file=sys.stderr)
        return 130
