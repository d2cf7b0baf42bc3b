"""Rules as small named functions, registered with ``@rule``; the first docstring line is their documentation.

A rule takes an ``EpisodeContext`` and returns its findings (an empty list: the rule holds). It raises
``Skip`` when its inputs are absent or unusable (the schema rules report why).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from univtac_data.validators.report import Finding

GROUPS: tuple[str, ...] = ("schema", "safety", "physics")

#: An episode rule takes an ``EpisodeContext``; a dataset rule a ``DatasetView``.
RuleFunc = Callable[[Any], list[Finding]]


class Skip(Exception):
    """A rule cannot run on this episode; ``str(error)`` says why (one line)."""


@dataclass(frozen=True)
class Rule:
    """A registered check: name, group, one-line documentation and the threshold it compares against.

    ``threshold`` names a ``ValidationConfig`` field, or ``profile.<field>`` of the sensor profile.
    """

    name: str
    group: str
    doc: str
    threshold: str | None
    func: RuleFunc
    scope: str = "episode"  # "episode": func takes an EpisodeContext; "dataset": a DatasetView


RULES: dict[str, Rule] = {}


def rule(name: str, group: str, threshold: str | None = None, scope: str = "episode") \
        -> Callable[[RuleFunc], RuleFunc]:
    """Register ``func`` as rule ``name`` of ``group``."""
    if group not in GROUPS:
        raise ValueError(f"group must be one of {GROUPS} (got {group!r})")

    def register(func: RuleFunc) -> RuleFunc:
        if name in RULES:
            raise ValueError(f"rule {name!r} is registered twice")
        summary = (func.__doc__ or "").strip().split("\n\n")[0]
        if not summary:
            raise ValueError(f"rule {name!r} needs a docstring")
        doc = " ".join(line.strip() for line in summary.splitlines())
        RULES[name] = Rule(name=name, group=group, doc=doc, threshold=threshold, func=func, scope=scope)
        return func

    return register


def frame_finding(field: str, bad: np.ndarray, values: np.ndarray, what: str, max_listed: int, *,
                  limits: np.ndarray | None = None, frame_offset: int = 0, unit: str = "") -> Finding | None:
    """A finding for the frames where ``bad`` is true (None when none is).

    ``values[k]`` is the offending value at frame ``k + frame_offset`` (offset 1 for per-interval values,
    where interval ``k`` ends at frame ``k + 1``); ``what`` completes "N frame(s) ...".
    """
    bad = np.asarray(bad, dtype=bool)
    idx = np.flatnonzero(bad)
    if idx.size == 0:
        return None
    listed = idx[:max_listed]
    vals = np.asarray(values, dtype=np.float64)
    first = float(vals[idx[0]])
    suffix = f" {unit}" if unit else ""
    message = (f"{field}: {idx.size} frame(s) {what}; first at frame {int(idx[0]) + frame_offset} "
               f"(value {first:.6g}{suffix}")
    if limits is not None:
        message += f", limit {float(np.asarray(limits)[idx[0]]):.6g}{suffix}"
    message += ")"
    return Finding(
        message=message, field=field, frames=[int(i) + frame_offset for i in listed],
        values=[float(v) for v in vals[listed]],
        limits=[] if limits is None else [float(v) for v in np.asarray(limits, dtype=np.float64)[listed]],
        n_frames=int(idx.size),
    )


def collect(findings: Sequence[Finding | None]) -> list[Finding]:
    """Drop the Nones of ``frame_finding`` calls."""
    return [f for f in findings if f is not None]


def rules_in(groups: Sequence[str], scope: str = "episode") -> list[Rule]:
    """Registered rules of ``groups`` and ``scope``, in registration order."""
    return [r for r in all_rules() if r.group in groups and r.scope == scope]


def all_rules() -> list[Rule]:
    """Every registered rule, grouped in ``GROUPS`` order, in registration order within a group."""
    from univtac_data.validators import rules_physics, rules_safety, rules_schema, rules_tactile, rules_task  # noqa: F401

    return sorted(RULES.values(), key=lambda r: GROUPS.index(r.group))


def rule_table_markdown() -> str:
    """The rule table of ``spec/validation.md``, generated from the registry."""
    lines = ["| rule | group | scope | threshold | checks |", "|---|---|---|---|---|"]
    for r in all_rules():
        threshold = f"`{r.threshold}`" if r.threshold else "-"
        lines.append(f"| `{r.name}` | {r.group} | {r.scope} | {threshold} | {r.doc} |")
    return "\n".join(lines)
