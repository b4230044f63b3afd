"""The tracker's exception: bad input to tracking or segmentation, under the package's error
hierarchy (a `TofcutError`, and a `ValueError` as it always was)."""

from __future__ import annotations

from tofcut.driver.errors import TofcutError


class SegmentError(TofcutError, ValueError):
    """A target, parameter or array that tracking or segmentation cannot use (the message
    says which)."""
