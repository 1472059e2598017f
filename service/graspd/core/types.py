"""The array type aliases every layer shares (one definition each): float64 and float32 arrays, int64 arrays."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

F64 = NDArray[np.float64]
F32 = NDArray[np.float32]
I64 = NDArray[np.int64]
