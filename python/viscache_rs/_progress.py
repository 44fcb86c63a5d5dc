"""Progress bars of the long calls. The core draws nothing: it reports ``(done, total)``
through a callback (about every 0.1 s, or after every wave or pass) and this module turns
the reports into a tqdm bar. Ctrl-C and time budgets are the core's business and work the
same with or without a bar."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Literal

from tqdm.auto import tqdm

#: What the core's long calls take as ``callback``: ``(done, total) -> go on``.
Callback = Callable[[int, int], bool]


@contextmanager
def progress_bar(
    show: bool,
    desc: str,
    unit: str,
    total: float | None | Literal["reported"] = "reported",
    per_unit: float = 1.0,
) -> Iterator[Callback | None]:
    """Yields the callback to pass to a core call, drawing a bar of ``done / per_unit``
    ``unit``s out of ``total`` (a number, None for unknown, or "reported": the total of
    each report, over ``per_unit``), or None when ``show`` is False. The bar is closed on
    leaving, also when the call raises (KeyboardInterrupt included)."""
    if not show:
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
