"""Results written for JSON or YAML, which hold no NaN or infinity: every non-finite float as
None (a scene file's spread, a command's --json report)."""
from __future__ import annotations

import math


def json_safe(value):
    """``value`` with every non-finite float, in dicts, lists and tuples too, as None."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    return value


__all__ = ['json_safe']
