"""Progress on stderr: a tqdm bar on a terminal, plain periodic lines anywhere else (CI logs, cluster jobs).

A bar redrawn with carriage returns turns a log file into one unreadable line, and no output at all looks like a
hang; so when stderr is not a terminal, ``Progress`` prints ``desc: done/total unit (postfix)`` at most every
``interval_s`` seconds, and once more at the end.
"""

from __future__ import annotations

import sys
import time
from typing import Any, TextIO

from tqdm import tqdm

PLAIN_INTERVAL_S = 10.0


class Progress:
    """Counts finished items out of ``total``; ``enabled=False`` prints nothing."""

    def __init__(self, total: int, *, desc: str, unit: str = "episode", initial: int = 0, enabled: bool = True,
                 stream: TextIO | None = None, interval_s: float = PLAIN_INTERVAL_S) -> None:
        self.stream = stream if stream is not None else sys.stderr
        self.total, self.done, self.desc, self.unit = total, initial, desc, unit
        self.enabled = enabled
        self.interval_s = interval_s
        self.postfix: dict[str, Any] = {}
        self._bar = None
        self._last_line = time.monotonic()
        self._printed_done = -1
        if enabled and _is_terminal(self.stream):
            self._bar = tqdm(total=total, initial=initial, unit=unit, desc=desc, file=self.stream,
                             dynamic_ncols=True)

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def update(self, n: int = 1, **postfix: Any) -> None:
        self.done += n
        self.postfix.update(postfix)
        if not self.enabled:
            return
        if self._bar is not None:
            if postfix:
                self._bar.set_postfix(**postfix, refresh=False)
            self._bar.update(n)
            return
        now = time.monotonic()
        if now - self._last_line >= self.interval_s or self.done >= self.total:
            self._line()
            self._last_line = now

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
        elif self.enabled and self._printed_done != self.done:
            self._line()

    def _line(self) -> None:
        extra = ", ".join(f"{k} {v}" for k, v in self.postfix.items())
        percent = f" ({100 * self.done / self.total:.0f} %)" if self.total else ""
        print(f"{self.desc}: {self.done}/{self.total} {self.unit}s{percent}{'; ' + extra if extra else ''}",
              file=self.stream, flush=True)
        self._printed_done = self.done


def _is_terminal(stream: TextIO) -> bool:
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):
        return False
