"""Progress for long work: a bar on a terminal, a line every few seconds in logs and CI."""

from __future__ import annotations

import sys
import time
from collections.abc import Callable, Iterable, Iterator
from typing import TypeVar

T = TypeVar("T")


def progress(
    items: Iterable[T],
    total: int | None,
    description: str,
    every_s: float = 5.0,
    counts: Callable[[T], bool] = lambda _: True,
) -> Iterator[T]:
    """Yield ``items`` while showing how far along the work is, on stderr only.

    ``counts`` says which items are units of work (frames) when others pass through too.
    """
    if sys.stderr.isatty():
        from rich.progress import Progress

        with Progress(transient=True) as bar:
            task = bar.add_task(description, total=total)
            for item in items:
                yield item
                if counts(item):
                    bar.advance(task)
        return
    last = time.monotonic()
    done = 0
    for item in items:
        yield item
        done += counts(item)
        now = time.monotonic()
        if now - last >= every_s:
            last = now
            of = f"/{total}" if total else ""
            print(f"{description}: {done}{of}", file=sys.stderr, flush=True)
