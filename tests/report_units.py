"""The report unit rule as a check: accuracy figures in reports are in mm, degrees or pixels."""

from __future__ import annotations

ACCURACY_WORDS = ("error", "scatter", "residual", "chamfer", "accuracy", "correction", "distance")


def keys_breaking_the_unit_rule(report: dict, path: str = "") -> list[str]:
    """Keys of numeric accuracy figures named in metres or radians (or with no unit at all)."""
    wrong = []
    for key, value in report.items():
        where = f"{path}.{key}" if path else str(key)
        if isinstance(value, dict):
            wrong += keys_breaking_the_unit_rule(value, where)
            continue
        numbers = value if isinstance(value, list) else [value]
        numeric = bool(numbers) and all(
            isinstance(v, int | float) and not isinstance(v, bool) for v in numbers
        )
        accuracy = any(w in str(key) for w in ACCURACY_WORDS)
        if numeric and accuracy and not str(key).endswith(("_mm", "_deg", "_px")):
            wrong.append(where)
    return wrong
