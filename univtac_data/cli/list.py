"""``univtac-data list sensors|shapes|tasks``: the names other commands accept, one per line with a description."""

from __future__ import annotations

import argparse
import importlib
from collections.abc import Iterable
from typing import Any

TASK_REGISTRY = "univtac_data.generators.tasks.registry"


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(
        "list", help="list the sensor profiles, indenter shapes or tasks by name",
        description="Print the names that --sensor, --shapes and task options accept, one per line with a short "
                    "description.",
        epilog="examples:\n  univtac-data list shapes\n  univtac-data generate indenters --shapes "
               "\"$(univtac-data list shapes --names | head -3 | paste -sd,)\"",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("what", choices=("sensors", "shapes", "tasks"), help="what to list")
    parser.add_argument("--names", action="store_true", help="names only, no descriptions")
    return parser


def sensor_entries() -> list[tuple[str, str]]:
    from univtac_data.schema.sensors import SENSORS

    return [(name, profile.display_name) for name, profile in SENSORS.items()]


def shape_entries() -> list[tuple[str, str]]:
    from univtac_data.generators.indenters.shapes import INDENTERS

    return [(name, f"{'convex' if ind.convex else 'non-convex'}: {ind.description}")
            for name, ind in INDENTERS.items()]


def task_entries() -> list[tuple[str, str]]:
    """The tasks ``univtac_data.generators.tasks.registry`` registers; none when the package has no tasks."""
    try:
        registry = importlib.import_module(TASK_REGISTRY)
    except ModuleNotFoundError as error:
        if error.name is not None and TASK_REGISTRY.startswith(error.name):
            return []
        raise
    for attr in ("TASKS", "REGISTRY", "task_names", "list_tasks", "names"):
        if hasattr(registry, attr):
            found = getattr(registry, attr)
            return _entries(found() if callable(found) else found)
    return []


def _entries(found: Any) -> list[tuple[str, str]]:
    items: Iterable[tuple[str, Any]] = found.items() if isinstance(found, dict) else ((n, None) for n in found)
    out = []
    for name, value in items:
        doc = getattr(value, "description", None) or (getattr(value, "__doc__", None) if value is not None else None)
        first = str(doc).strip().splitlines()[0] if doc and not isinstance(value, (str, int, float)) else ""
        out.append((str(name), first))
    return sorted(out)


def run(args: argparse.Namespace) -> int:
    entries = {"sensors": sensor_entries, "shapes": shape_entries, "tasks": task_entries}[args.what]()
    if not entries:
        print(f"(no {args.what})")
        return 0
    width = max(len(name) for name, _ in entries)
    for name, text in entries:
        print(name if args.names or not text else f"{name:<{width}}  {text}")
    return 0
