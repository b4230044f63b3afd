"""The array type every layer annotates with, named once: float64 arrays (points, ranges,
rays, costs) are what the driver, the emulator, the tracker and the tools pass around."""

import numpy as np
import numpy.typing as npt

F64 = npt.NDArray[np.float64]
"""A float64 array of any shape (the shape is said where it is used)."""
