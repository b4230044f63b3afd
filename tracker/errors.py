"""The tracker's exception: bad input to segmentation, under the package's error hierarchy."""

from __future__ import annotations

from tofcut.driver.errors import TofcutError


class SegmentError(TofcutError, ValueError):
    """A target, parameter or array that segmentation cannot use (the message says which)."""
