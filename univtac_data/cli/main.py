"""``univtac-data``: one entry point, one module per subcommand.

Each subcommand module has ``add_parser(subparsers)`` and ``run(args) -> int``. Errors a user can cause
(``DatasetError``) print one line and exit 2; Ctrl-C at any point (start-up included) prints one line and exits
130; anything else is a bug and keeps its traceback.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
from typing import NoReturn

from univtac_data.version import FORMAT_VERSION, __version__

SUBCOMMANDS = ("generate", "validate", "info", "convert", "reindex", "preview", "export", "evaluate", "list")

EXAMPLES = """examples:
  univtac-data generate indenters                      make the default corpus in out/indenters
  univtac-data validate out/indenters                  check it (exit 0 clean, 1 failures, 2 unusable input)
  univtac-data info out/indenters                      episodes, frames, size; checks the files are all there
  univtac-data preview out/indenters --gallery --out gallery.png
  univtac-data convert out/indenters out/zarr --to zarr
  univtac-data generate task lift_can --episodes 10    expert demonstrations of a benchmark task
  univtac-data evaluate lift_can --policy expert       a policy's success rate on evaluation seeds
  univtac-data list shapes                             names accepted by --shapes (also: sensors, tasks)

Run 'univtac-data COMMAND --help' for a command's options and examples."""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="univtac-data",
        description="Visuo-tactile robot data: generate, validate, inspect and convert univtac-data datasets.",
        epilog=EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"univtac-data {__version__} (format {FORMAT_VERSION})")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in SUBCOMMANDS:
        module = importlib.import_module(f"univtac_data.cli.{name}")
        sub = module.add_parser(subparsers)
        sub.set_defaults(_run=module.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    try:
        return _main(argv)
    except KeyboardInterrupt:
        print("univtac-data: interrupted", file=sys.stderr)
        return 130


def _main(argv: list[str] | None) -> int:
    from univtac_data.storage.errors import DatasetError  # loads the storage stack: inside main's Ctrl-C guard

    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args._run(args))
    except DatasetError as error:
        print(f"univtac-data: error: {error}", file=sys.stderr)
        return 2


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
