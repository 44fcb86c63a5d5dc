"""Progress bars of the long calls. The core draws nothing: it reports ``(done, total)``
through a callback (about every 0.1 s, or after every wave or pass) and this module turns
the reports into a tqdm bar. Ctrl-C and time budgets are the core's business and work the
same with or without a bar."""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Literal

from tqdm.auto import tqdm

#: What the core's long calls take as ``callback``: ``(done, total) -> go on``.
Callback = Callable[[int, int], bool]


def wants_bar(show: bool | None) -> bool:
    """Whether a call given ``progress=show`` draws a bar: ``show`` itself when it is a
    bool; for None, whether ``sys.stderr`` (where tqdm draws) is a terminal."""
    if show is not None:
        return bool(show)
    try:
        return sys.stderr is not None and sys.stderr.isatty()
    except (AttributeError, ValueError):  # no isatty, or a closed stream
        return False


@contextmanager
def progress_bar(
    show: bool | None,
    desc: str,
    unit: str,
    total: float | None | Literal["reported"] = "reported",
    per_unit: float = 1.0,
) -> Iterator[Callback | None]:
    """Yields the callback to pass to a core call, drawing a bar of ``done / per_unit``
    ``unit``s out of ``total`` (a number, None for unknown, or "reported": the total of
    each report, over ``per_unit``), or None when no bar is drawn (:func:`wants_bar`:
    ``show`` False, or None and stderr not a terminal); without a bar the core gets no
    callback at all. The bar is closed on
    leaving, also when the call raises (KeyboardInterrupt included)."""
    if not wants_bar(show):
        yield None
        return
    bar = tqdm(total=None if total == "reported" else total, desc=desc, unit=unit,
               leave=False)

    def scaled(n: int) -> float:
        return n if per_unit == 1 else n / per_unit

    def report(done: int, reported_total: int) -> bool:
        if total == "reported":
            bar.total = scaled(reported_total)
        bar.update(scaled(done) - bar.n)
        return True

    try:
        yield report
    finally:
        bar.close()
