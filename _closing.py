"""`Closing`: how whatever holds something open (a camera, a file, a process, a port) closes
at the end of a `with` block, written once."""

from __future__ import annotations

from types import TracebackType
from typing import Self


class Closing:
    """A context manager that closes: `with x:` gives `x` and calls `x.close()` when the block
    ends, however it ends. A subclass defines `close`; one that opens on entering overrides
    `__enter__`."""

    def close(self) -> None:
        raise NotImplementedError

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()
