"""``univtac-data validate PATH [--json] [--workers N] [--episodes ID,...] [--groups schema,safety,physics]``.

Exit status: 0 every check holds; 1 an episode (or the dataset's metadata) fails a check; 2 the input is
unusable (missing path, not a dataset, unreadable info.json or index, another major format version).
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

from univtac_data.storage.errors import DatasetError
from univtac_data.validators import GROUPS, Report, parse_groups, validate
from univtac_data.cli.args import positive_int

MAX_LISTED_FINDINGS = 40  # lines of failures in the table output; --json has them all


def _groups(text: str) -> tuple[str, ...]:
    try:
        return parse_groups(text)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


def _ids(text: str) -> list[str]:
    ids = [part.strip() for part in text.split(",") if part.strip()]
    if not ids:
        raise argparse.ArgumentTypeError("give at least one episode id")
    return ids



def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(
        "validate", help="check a dataset: schema, safety limits and physical invariants",
        description="Check every episode of a dataset: decode every chunk, hash every byte, run the named rules "
                    "of spec/validation.md. Exit 0: all checks hold; 1: an episode fails; 2: the input is "
                    "unusable (or bad usage).",
        epilog="examples:\n  univtac-data validate out/indenters\n"
               "  univtac-data validate out/indenters --json --workers 2 --groups safety,physics\n"
               "  univtac-data validate out/indenters --episodes gelsight_mini-cone-0000",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("path", help="dataset directory or fsspec URL")
    parser.add_argument("--json", action="store_true", help="print the full report as JSON")
    parser.add_argument("--workers", type=positive_int, default=1, metavar="N",
                        help="processes checking episodes in parallel (default 1)")
    parser.add_argument("--episodes", type=_ids, default=None, metavar="ID,...",
                        help="check only these episode ids (default: every indexed episode)")
    parser.add_argument("--groups", type=_groups, default=GROUPS, metavar="GROUP,...",
                        help=f"rule groups to run, among {','.join(GROUPS)} (default: all)")
    return parser


def format_table(report: Report) -> str:
    """The human-readable report: one line per episode, then the failures, then a summary line."""
    lines = [f"dataset  {report.dataset} ({report.storage}, format {report.format_version}); "
             f"groups: {', '.join(report.groups)}"]
    width = max([len("episode"), *(len(e) for e in report.episodes)])
    lines.append(f"{'episode':<{width}}  {'frames':>7}  status  failed rules")
    for eid, episode in report.episodes.items():
        failed = ", ".join(c.rule for c in episode.failed_checks())
        frames = "-" if episode.n_frames is None else str(episode.n_frames)
        lines.append(f"{eid:<{width}}  {frames:>7}  {'ok' if episode.ok else 'FAIL':<6}  {failed}".rstrip())
    failures = [("dataset", c.rule, f.message) for c in report.dataset_checks if c.failed for f in c.findings]
    failures += [(eid, c.rule, f.message) for eid, e in report.episodes.items() for c in e.failed_checks()
                 for f in c.findings]
    if failures:
        lines.append("failures:")
        for where, rule, message in failures[:MAX_LISTED_FINDINGS]:
            lines.append(f"  {where}  {rule}  {message}")
        if len(failures) > MAX_LISTED_FINDINGS:
            lines.append(f"  ... {len(failures) - MAX_LISTED_FINDINGS} more (use --json for all)")
    n_failed = len(report.failed_episodes())
    total_frames = sum(e.n_frames or 0 for e in report.episodes.values())
    dataset_failed = sum(c.failed for c in report.dataset_checks)
    verdict = "OK" if report.ok else "FAILED"
    lines.append(f"{verdict}: {n_failed} of {len(report.episodes)} episode(s) failed, {total_frames} frames checked; "
                 f"{dataset_failed} dataset check(s) failed")
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    from univtac_data.storage import Dataset

    try:
        if args.episodes is not None:  # an unknown id is bad usage (exit 2), not a failing episode
            known = Dataset.open(args.path).index
            unknown = [e for e in args.episodes if e not in known]
            if unknown:
                listed = ", ".join(sorted(known)[:5]) + (" ..." if len(known) > 5 else "")
                raise DatasetError(f"{args.path}: --episodes: no episode {', '.join(map(repr, unknown))} in the "
                                   f"index (episodes: {listed or 'none'})")
        report = validate(args.path, groups=args.groups, episodes=args.episodes, workers=args.workers,
                          progress=True)
    except DatasetError as error:
        print(f"univtac-data: error: {error}", file=sys.stderr)
        return 2
    print(report.to_json() if args.json else format_table(report))
    return 0 if report.ok else 1


def main(argv: list[str] | None = None) -> int:
    """Run ``validate`` alone (``python -m univtac_data.cli.validate PATH ...``)."""
    parser = argparse.ArgumentParser(prog="univtac-data")
    subparsers = parser.add_subparsers(dest="command", required=True)
    add_parser(subparsers)
    return run(parser.parse_args(["validate", *(sys.argv[1:] if argv is None else argv)]))


if __name__ == "__main__":
    sys.exit(main())
