"""numpy's `clip` and `count_nonzero` without their Python layers, for a cycle's tiny arrays.

`np.clip` reaches the clip ufunc, and `np.count_nonzero` its C function, through Python layers
that cost several times the work on a few joints; called directly (`clip` with `out=`) they give
the same values and allocate nothing.
"""

from __future__ import annotations

from typing import Any

import numpy as np

_core: Any = getattr(np, "_core", None) or np.core  # numpy 2, or 1.x
clip: Any = getattr(getattr(_core, "umath", None), "clip", None) or np.clip
count_nonzero: Any = getattr(getattr(_core, "multiarray", None), "count_nonzero", None) or np.count_nonzero

__all__ = ["clip", "count_nonzero"]
