"""numpy's `clip` as the ufunc it is, for a cycle's tiny arrays.

`np.clip` reaches the same ufunc through Python layers that cost several times the clipping of
a few joints; the ufunc itself, called with `out=`, gives the same values and allocates nothing.
"""

from __future__ import annotations

from typing import Any

import numpy as np

_core: Any = getattr(np, "_core", None) or np.core  # numpy 2, or 1.x
clip: Any = getattr(getattr(_core, "umath", None), "clip", None) or np.clip

__all__ = ["clip"]
