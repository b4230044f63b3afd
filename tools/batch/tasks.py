"""Run one function over many items (captures, seeds, settings) on a `Pool`: each item one
task, a task that fails tried once more, and every outcome kept, in the items' order.

A task fails when it raises, when its worker dies, or when `failure` finds an error in what
it returned (a family's line that could not be recorded, say). The second attempt's outcome
is the one kept, with the first attempt's error beside it: nothing is dropped.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Generic, TypeVar

from tofcut.tools.batch.pool import Pool
from tofcut.tools.batch.steps import describe

T = TypeVar("T")
R = TypeVar("R")

ATTEMPTS = 2
"""A failed task is tried once more, no more: a failure that repeats is the item's."""


@dataclass(frozen=True)
class Outcome(Generic[T, R]):
    """One item's task: what it returned (None if it raised or its worker died), why its
    last attempt failed, and why the first did when it was tried again."""

    item: T
    result: R | None
    error: str | None = None
    retried: str | None = None

    @property
    def failed(self) -> bool:
        return self.error is not None


def _no_failure(result: Any) -> str | None:
    return None


def _call(fn: Callable[[T], R], item: T) -> R:
    """A task on Ray: `fn` may be any callable (a partial, say), which `ray.remote` is not."""
    return fn(item)


def _describe_ray(exc: BaseException) -> str:
    """A Ray error in one line: the task's own exception, or how its worker was lost."""
    cause = getattr(exc, "cause", None)
    if isinstance(cause, BaseException) and not type(cause).__module__.startswith("ray"):
        return describe(cause)
    first = str(exc).strip().splitlines()
    return f"the task's worker was lost ({type(exc).__name__}: {first[0] if first else ''})"


def run_tasks(
    fn: Callable[[T], R],
    items: Sequence[T],
    pool: Pool,
    *,
    failure: Callable[[R], str | None] = _no_failure,
    on_done: Callable[[Outcome[T, R]], None] = lambda o: None,
    on_retry: Callable[[T, str], None] = lambda item, why: None,
) -> list[Outcome[T, R]]:
    """`fn(item)` for every item, on the pool; the outcomes in the order of the items."""
    outcomes: dict[int, Outcome[T, R]] = {}
    first: dict[int, str] = {}

    def settle(index: int, attempt: int, result: R | None, why: str | None) -> bool:
        """Keep an attempt's outcome; False when the task is to be tried again."""
        if why is not None and attempt < ATTEMPTS:
            first[index] = why
            on_retry(items[index], why)
            return False
        outcome = Outcome(items[index], result, why, first.get(index))
        outcomes[index] = outcome
        on_done(outcome)
        return True

    if pool.ray is None:
        for index, item in enumerate(items):
            for attempt in range(1, ATTEMPTS + 1):
                try:
                    result: R | None = fn(item)
                    why = failure(result) if result is not None else None
                except Exception as exc:
                    result, why = None, describe(exc)
                if settle(index, attempt, result, why):
                    break
        return [outcomes[i] for i in range(len(items))]

    ray = pool.ray
    remote = ray.remote(num_cpus=1, max_retries=0)(_call)  # retried here, where it is seen
    queue = deque((index, 1) for index in range(len(items)))
    running: dict[Any, tuple[int, int]] = {}
    while queue or running:
        while queue and len(running) < pool.workers:
            index, attempt = queue.popleft()
            running[remote.remote(fn, items[index])] = (index, attempt)
        [ref], _ = ray.wait(list(running), num_returns=1)
        index, attempt = running.pop(ref)
        try:
            result = ray.get(ref)
            why = failure(result) if result is not None else None
        except ray.exceptions.RayError as exc:
            result, why = None, _describe_ray(exc)
        if not settle(index, attempt, result, why):
            queue.appendleft((index, attempt + 1))
    return [outcomes[i] for i in range(len(items))]


def failure_sections(
    failed: Sequence[tuple[str, str]], retried: Sequence[tuple[str, str]]
) -> list[str]:
    """Markdown lines saying what failed and what was run twice (what, why), if any did."""
    out = []
    if failed:
        out += ["", "## Failed", "", *(f"- {what}: {why}" for what, why in failed)]
    if retried:
        out += ["", "## Run twice", ""]
        out += [f"- {what}: the first run failed: {why}" for what, why in retried]
    return out
