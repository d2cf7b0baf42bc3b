"""Validators: small named rules in three groups (schema, safety, physics) and one entry point.

>>> from univtac_data.validators import validate
>>> report = validate("data/my_dataset", groups=("schema", "safety"))   # doctest: +SKIP
>>> report.ok, report.failed_episodes()                                    # doctest: +SKIP

The rule table (``rule_table_markdown()``) is what ``spec/validation.md`` quotes.
"""

from univtac_data.validators.config import ValidationConfig
from univtac_data.validators.registry import GROUPS, RULES, Rule, rule_table_markdown, rules_in
from univtac_data.validators.report import REPORT_VERSION, CheckResult, EpisodeReport, Finding, Report
from univtac_data.validators.runner import parse_groups, validate, validate_episode

__all__ = [
    "GROUPS", "REPORT_VERSION", "RULES", "CheckResult", "EpisodeReport", "Finding", "Report", "Rule",
    "ValidationConfig", "parse_groups", "rule_table_markdown", "rules_in", "validate", "validate_episode",
]
