"""How the tracker's per-pixel loops are compiled, and their warm-up before the first frame.

The loops are compiled with numba (one thread, cached on disk), each in a module beside the
code it serves (`cut_kernels` beside the cut, `background_kernels` beside the background
model, ...: every `tofcut.tracker.*_kernels` module). Each kernel does the same
floating-point operations in the same order as the numpy expressions it replaces
(`tofcut.tracker.reference` holds those), with numpy's rules for division by zero, so the
tracker's output does not change.

A kernel module compiles each kernel the tracker calls with `kernel`, naming the argument
types it is called with by example arguments (only their numba types count: dtype,
dimensions, layout; the arrays below, and Python's `1` and `1.0` for int64 and float64), and
each kernel only other kernels call with `helper` (it is compiled into its callers).
`warm_up` then loads (or compiles) every kernel registered, for every example: a live run
does not stall on one mid-stream. A test finds every compiled function in the kernel modules
and fails on one registered neither way.
"""

from __future__ import annotations

import importlib
import pkgutil
from collections.abc import Callable
from typing import Any, TypeVar, cast

import numba
import numpy as np

F = TypeVar("F", bound=Callable[..., Any])
Example = tuple[object, ...]
"""Arguments a kernel is called with, by example: one tuple per argument types."""

OPTIONS: dict[str, Any] = {"cache": True, "nogil": True, "error_model": "numpy"}
"""How every kernel is compiled: cached on disk, without the GIL, numpy's rules for errors."""

KERNELS: dict[str, tuple[Any, tuple[Example, ...]]] = {}
"""Each kernel the tracker calls, by module and name: its dispatcher and its examples."""
HELPERS: dict[str, Any] = {}
"""Each kernel only other kernels call, by module and name: its dispatcher."""

# example arguments, one of each array type the tracker passes (C order unless said)
F64_1D = np.zeros(1)
F64_2D = np.zeros((1, 1))
F64_2D_F = np.zeros((2, 3), order="F")
"""In Fortran order: columns taken out of a (labels, nodes) array (`multicut`)."""
F64_3D = np.zeros((1, 1, 1))
F32_2D = np.zeros((1, 1), np.float32)
B_1D = np.zeros(1, np.bool_)
B_2D = np.zeros((1, 1), np.bool_)
I64_1D = np.zeros(1, np.int64)
I64_2D = np.zeros((1, 1), np.int64)
I32_2D = np.zeros((1, 1), np.int32)
U16_2D = np.zeros((1, 1), np.uint16)


def kernel(*examples: Example) -> Callable[[F], F]:
    """Compile a kernel the tracker calls, and register it for `warm_up` with `examples`: the
    arguments of each argument types it is called with."""
    if not examples:
        raise TypeError("a kernel needs an example of the arguments it is called with")

    def compiled(f: F) -> F:
        dispatcher = numba.njit(**OPTIONS)(f)
        KERNELS[f"{f.__module__}.{f.__qualname__}"] = (dispatcher, examples)
        return cast(F, dispatcher)

    return compiled


def helper(f: F) -> F:
    """Compile a kernel that only other kernels call (it is compiled into each, warmed up
    with them), and register it as such."""
    dispatcher = numba.njit(**OPTIONS)(f)
    HELPERS[f"{f.__module__}.{f.__qualname__}"] = dispatcher
    return cast(F, dispatcher)


def kernel_modules() -> list[str]:
    """The names of the tracker's kernel modules, `tofcut.tracker.*_kernels`."""
    import tofcut.tracker as package

    return sorted(
        f"{package.__name__}.{m.name}"
        for m in pkgutil.iter_modules(package.__path__)
        if m.name.endswith("_kernels")
    )


def warm_up() -> None:
    """Load (or compile) every kernel of every kernel module for each argument types it is
    registered with, and the driver's demodulation kernels, so the first frames of a live
    run do not stall on them (about a second from the disk cache, once per process)."""
    global _warm
    if _warm:
        return
    for name in [*kernel_modules(), "tofcut.driver.demod_kernels"]:  # demodulation's too
        importlib.import_module(name)
    for dispatcher, examples in KERNELS.values():
        for args in examples:
            dispatcher.compile(tuple(_typeof(a) for a in args))
    _warm = True


_warm = False
_typeof: Callable[[object], Any] = numba.typeof
"""The numba type of an argument (as a call's dispatch takes it)."""
