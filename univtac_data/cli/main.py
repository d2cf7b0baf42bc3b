"""``univtac-data``: one entry point, one module per subcommand.

Each subcommand module has ``add_parser(subparsers)`` and ``run(args) -> int``. Errors a user can cause
(``DatasetError``) print one line and exit 2; anything else is a bug and keeps its traceback.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
from typing import NoReturn

from univtac_data.storage.errors import DatasetError
from univtac_data.version import FORMAT_VERSION, __version__

SUBCOMMANDS = ("generate", "validate", "info", "convert", "reindex", "preview", "export", "evaluate")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="univtac-data",
        description="Visuo-tactile robot data: generate, validate, inspect and convert univtac-data datasets.",
    )
    parser.add_argument("--version", action="version", version=f"univtac-data {__version__} (format {FORMAT_VERSION})")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in SUBCOMMANDS:
        module = importlib.import_module(f"univtac_data.cli.{name}")
        sub = module.add_parser(subparsers)
        sub.set_defaults(_run=module.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args._run(args))
    except DatasetError as error:
        print(f"univtac-data: error: {error}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("univtac-data: interrupted", file=sys.stderr)
        return 130


def entry() -> NoReturn:
    """The console script: run ``main`` and end the process with its exit code.

    The process ends with ``os._exit`` after flushing stdout and stderr. Every command has closed and fsynced
    its files by the time ``main`` returns; what is skipped is the interpreter's teardown of native thread
    pools (Arrow's I/O pool, BLAS), which now and then aborted a finished run with "terminate called without
    an active exception" (exit -6) in CI-like runs, turning a success or a clean error into a crash.
    """
    try:
        code = main()
        sys.stdout.flush()
    except BrokenPipeError:  # the reader of stdout went away (`univtac-data info PATH | head`): not an error
        code = 0
    sys.stderr.flush()
    os._exit(code)


if __name__ == "__main__":
    entry()
