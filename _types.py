"""The array types every layer annotates with, named once: float64 arrays (points, ranges,
rays, costs) are what the driver, the emulator, the tracker and the tools pass around; masks,
indices and labels what the tracker's steps and kernels pass between them."""

import numpy as np
import numpy.typing as npt

F64 = npt.NDArray[np.float64]
"""A float64 array of any shape (the shape is said where it is used)."""
F32 = npt.NDArray[np.float32]
B = npt.NDArray[np.bool_]
"""A mask (or any bool array)."""
I64 = npt.NDArray[np.int64]
I32 = npt.NDArray[np.int32]
"""Pieces of a mask, numbered (`scipy.ndimage.label`'s type)."""
U16 = npt.NDArray[np.uint16]
"""Labels: 0 the background, else a track's id."""
U8 = npt.NDArray[np.uint8]
"""An image's grey levels or colours, as written to a file or shown."""
