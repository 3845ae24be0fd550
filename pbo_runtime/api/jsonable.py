"""Replies as plain JSON data: numpy values as numbers and lists, non-finite floats as null.

The API answers with it and `pbo VERB --format json` prints with it, so both show a reply alike.
"""

from __future__ import annotations

import math
from typing import Any

from pbo_runtime.ipc.control import plain


def jsonable(value: Any) -> Any:
    """`value` with numpy scalars and arrays as Python numbers and lists, and NaN/inf as None (JSON has neither)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple, set, frozenset)):
        return [jsonable(v) for v in value]
    if isinstance(value, (str, int, bool)) or value is None:
        return value
    return jsonable(plain(value))
