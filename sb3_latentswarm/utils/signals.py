"""One way to catch signals for the length of a ``with`` block (no torch or SB3 import: light for parent processes)."""

from __future__ import annotations

import signal
import threading
from typing import Any


class SignalHandlers:
    """Context manager: while inside, each signal of :attr:`SIGNALS` calls :meth:`_handle` instead of its previous
    handler, which is put back on exit; by default :meth:`_handle` records the signal in :attr:`received`. Handlers
    are installed only in the main thread (Python's rule); elsewhere this does nothing. Subclasses may set
    :attr:`SIGNALS` and override :meth:`_handle`.
    """

    SIGNALS: tuple[int, ...] = (signal.SIGINT, signal.SIGTERM)

    def __init__(self) -> None:
        self.received: list[int] = []
        self._previous: dict[int, Any] = {}

    def _handle(self, signum: int, frame: Any) -> None:
        self.received.append(signum)

    def __enter__(self) -> Any:
        if threading.current_thread() is threading.main_thread():
            for signum in self.SIGNALS:
                self._previous[signum] = signal.signal(signum, self._handle)
        return self

    def __exit__(self, *exc: Any) -> None:
        for signum, handler in self._previous.items():
            signal.signal(signum, handler)
        self._previous.clear()
