"""Where a batch's tasks run: one by one in this process, on a Ray started here on this
machine's cores (loopback only, stopped and its files removed at the end), or on an existing
Ray cluster (`--ray-address`).

Ray is an extra (`pip install 'tofcut[ray]'`): without it a batch runs one task at a time.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import logging
import os
import shutil
import tempfile
from pathlib import Path
from types import TracebackType
from typing import Any

from tofcut.driver.errors import TofcutError

log = logging.getLogger(__name__)

OBJECT_STORE_BYTES = 100 * 2**20
"""Ray's shared-memory store for a local run (its least is 75 MiB): tasks hand back tables
of scores, never frames, so Ray's default (30 % of the RAM) would only be memory held."""

LOCAL_ENVIRONMENT = {
    # The node's address is loopback (on Linux Ray otherwise takes the address it would
    # reach the internet from, and its servers listen there): nothing listens beyond it.
    # (Ray reads it for macOS and Windows, where it is the default.)
    "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER": "0",
    # No usage report to the internet.
    "RAY_USAGE_STATS_ENABLED": "0",
}
"""Set before Ray is imported (it reads them then) for a Ray started here."""

ENVIRONMENT = {
    # Under `uv run`, Ray would pack the working folder and run workers through uv: the
    # workers run this Python, with tofcut as installed.
    "RAY_ENABLE_UV_RUN_RUNTIME_ENV": "0",
}
"""Set before Ray is imported, for any run on Ray."""


class BatchError(TofcutError):
    """A batch cannot run where it was asked to (no Ray, no cluster at that address)."""


def cores() -> int:
    """The cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def have_ray() -> bool:
    """Whether Ray is installed (not imported: it reads its settings when it is)."""
    return importlib.util.find_spec("ray") is not None


def add_batch_options(g: argparse._ArgumentGroup | argparse.ArgumentParser, what: str) -> None:
    """`--workers` and `--ray-address`; `what` names a task (`lines`, `captures`)."""
    g.add_argument(
        "--workers", type=int, metavar="N",
        help=f"{what} at once, as Ray tasks (default: every core of this machine, "
        f"{cores()}, or with --ray-address the cluster's; 1: one by one in this process)",
    )  # fmt: skip
    g.add_argument(
        "--ray-address", metavar="HOST:PORT",
        help="run on this existing Ray cluster (`ray start --head` prints it; every node needs "
        "tofcut installed and the files at the same paths)",
    )  # fmt: skip


class Pool:
    """Where tasks run, as a context manager: `workers` at once; `ray` is the Ray module
    when they run on Ray, None when they run one by one here."""

    def __init__(self, workers: int | None = None, address: str | None = None) -> None:
        if workers is not None and workers < 1:
            raise BatchError("--workers must be at least 1")
        self.address = address
        self.asked = workers
        self.workers = workers or 1
        self.ray: Any = None
        self._temp: Path | None = None

    @classmethod
    def from_args(cls, args: argparse.Namespace) -> Pool:
        return cls(args.workers, args.ray_address)

    @property
    def where(self) -> str:
        """The pool in a few words, for the first line a batch prints."""
        if self.ray is None:
            return "one at a time"
        if self.address is not None:
            return f"{self.workers} at a time on the Ray cluster at {self.address}"
        return f"{self.workers} at a time on a local Ray"

    def __enter__(self) -> Pool:
        wants_ray = self.address is not None or self.asked is None or self.asked > 1
        if not wants_ray:
            return self
        if not have_ray():
            if self.address is not None or self.asked is not None:
                raise BatchError(
                    "running tasks at once or on a cluster needs Ray: pip install "
                    "'tofcut[ray]' (or --workers 1)"
                )
            log.warning("Ray is not installed: one task at a time (pip install 'tofcut[ray]')")
            return self
        if self.address is None and self.asked is None and cores() == 1:
            return self
        self._start()
        return self

    def _start(self) -> None:
        local = self.address is None
        os.environ.update({**ENVIRONMENT, **(LOCAL_ENVIRONMENT if local else {})})
        logger = logging.getLogger("ray")
        level = logger.level
        self.ray = ray = importlib.import_module("ray")  # typed loosely: ray's stubs are not
        logger.setLevel(level)  # Ray sets its own on import; the command line's rules hold
        options: dict[str, Any] = {
            "include_dashboard": False, "log_to_driver": False, "configure_logging": False,
        }  # fmt: skip
        try:
            if local:
                if ray.util.get_node_ip_address() not in ("127.0.0.1", "::1"):
                    raise BatchError(
                        "Ray would listen beyond loopback here (it was imported before "
                        "tofcut could set it up): run the batch in a process of its own"
                    )
                self.workers = self.asked or cores()
                self._temp = Path(tempfile.mkdtemp(prefix="tofcut-ray-"))
                ray.init(
                    address="local", num_cpus=self.workers, _temp_dir=str(self._temp),
                    object_store_memory=OBJECT_STORE_BYTES, **options,
                )  # fmt: skip
            else:
                ray.init(address=self.address, **options)
                self.workers = self.asked or max(1, int(ray.cluster_resources().get("CPU", 1)))
        except BatchError:
            self.close()
            raise
        except Exception as exc:
            self.close()
            where = "start Ray here" if local else f"reach the Ray cluster at {self.address}"
            text = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            raise BatchError(f"could not {where}: {text}") from exc

    def close(self) -> None:
        """Stop Ray (a local one with every process it started) and remove its files."""
        if self.ray is not None:
            self.ray.shutdown()
        if self._temp is not None:
            shutil.rmtree(self._temp, ignore_errors=True)
            self._temp = None

    def __exit__(
        self,
        kind: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()
