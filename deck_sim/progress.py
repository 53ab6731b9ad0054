"""Progress reporting for long work: a live bar on a terminal, plain lines in a log file.

``progress(...)`` takes the subset of tqdm's arguments that deck_sim uses. When stderr is a terminal it returns a
``tqdm`` bar; otherwise (CI, ``nohup``, a redirected log) a ``LineProgress`` that writes one plain line every
``interval`` seconds and one at the end, so a log file gets no carriage-return spam.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Iterable, Iterator, Mapping
from typing import Any, TextIO

LINE_INTERVAL_S = 30.0
"""Seconds between two progress lines when stderr is not a terminal."""


class LineProgress:
    """A progress report as plain lines: ``desc: n/total unit (pct) in t s, postfix``.

    Implements the part of tqdm's interface that deck_sim calls: iteration, ``update``, ``set_postfix``, ``write``,
    ``n``, ``close`` and use as a context manager.
    """

    def __init__(
        self,
        iterable: Iterable[Any] | None = None,
        *,
        total: float | None = None,
        initial: float = 0,
        desc: str = "",
        unit: str = "it",
        disable: bool = False,
        leave: bool = True,
        interval: float = LINE_INTERVAL_S,
        file: TextIO | None = None,
    ) -> None:
        self.iterable = iterable
        if total is None and iterable is not None and hasattr(iterable, "__len__"):
            total = len(iterable)  # type: ignore[arg-type]
        self.total = total
        self.n = initial
        self.desc = desc
        self.unit = unit
        self.disable = disable
        self.leave = leave
        self.interval = interval
        self.file = file if file is not None else sys.stderr
        self._postfix = ""
        self._start = time.monotonic()
        self._last = self._start
        self._closed = False

    def __iter__(self) -> Iterator[Any]:
        if self.iterable is None:
            raise TypeError("this progress report was made without an iterable")
        for item in self.iterable:
            yield item
            self.update(1)

    def __enter__(self) -> LineProgress:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def update(self, n: float = 1) -> None:
        """Count ``n`` more units of work; print a line if ``interval`` seconds have passed since the last."""
        self.n += n
        now = time.monotonic()
        if now - self._last >= self.interval:
            self._last = now
            self._print()

    def set_postfix(self, ordered_dict: Mapping[str, Any] | None = None, refresh: bool = True, **kwargs: Any) -> None:
        """Values shown after the count (as tqdm's ``set_postfix``); printed with the next line."""
        del refresh
        items = {**(ordered_dict or {}), **kwargs}
        self._postfix = ", ".join(f"{k}={v}" for k, v in items.items())

    def write(self, text: str) -> None:
        """Print a message on its own line (as tqdm's ``write``)."""
        if not self.disable:
            print(text, file=self.file, flush=True)

    def close(self) -> None:
        """Print the final line (unless ``leave`` is false or the report is disabled)."""
        if not self._closed and self.leave:
            self._print()
        self._closed = True

    def _print(self) -> None:
        if self.disable:
            return
        count = _count(self.n) if self.total is None else f"{_count(self.n)}/{_count(self.total)}"
        share = f" ({100 * self.n / self.total:.0f} %)" if self.total else ""
        line = f"{self.desc}: {count} {self.unit}{share} in {time.monotonic() - self._start:.0f} s"
        if self._postfix:
            line += f", {self._postfix}"
        print(line, file=self.file, flush=True)


def progress(iterable: Iterable[Any] | None = None, **kwargs: Any) -> Any:
    """A tqdm bar when stderr is a terminal, else a ``LineProgress`` with the same arguments.

    Accepted keywords: ``total``, ``initial``, ``desc``, ``unit``, ``disable``, ``leave``.
    """
    if _is_terminal(sys.stderr):
        from tqdm import tqdm

        return tqdm(iterable, **kwargs)
    return LineProgress(iterable, **kwargs)


def _is_terminal(stream: TextIO) -> bool:
    try:
        return stream.isatty()
    except (AttributeError, ValueError):  # a closed or replaced stream
        return False


def _count(x: float) -> str:
    """A count as printed: whole numbers in full (``1000000``, not ``1e+06``), others to 6 significant digits."""
    return str(int(x)) if float(x).is_integer() else f"{x:g}"
