"""A bounded memo of results that threads share: the diagnosis asks for the same costly replay or
estimate at several stages, and keeps the last few (least recently used out first)."""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Callable, Hashable
from typing import Any


class Memo:
    """The last ``size`` results by key, least recently used out first; safe to share between threads
    (two threads asking for the same missing key both compute it, and the later result is kept).

    Parameters
    ----------
    size : int
        The results kept.
    """

    def __init__(self, size: int) -> None:
        self.size = size
        self._kept: OrderedDict[Hashable, Any] = OrderedDict()
        self._lock = threading.Lock()

    def get(self, key: Hashable, compute: Callable[[], Any], valid: Callable[[Any], bool] | None = None,
            seal: Callable[[Any], None] | None = None) -> Any:
        """The result kept for ``key`` (when ``valid`` accepts it), else ``compute()``, kept.
        ``seal``: applied to a fresh result before it is kept and shared (say, making arrays read-only)."""
        with self._lock:
            hit = self._kept.get(key, _MISSING)
            if hit is not _MISSING and (valid is None or valid(hit)):
                self._kept.move_to_end(key)
                return hit
        out = compute()
        if seal is not None:
            seal(out)
        with self._lock:
            self._kept[key] = out
            while len(self._kept) > self.size:
                self._kept.popitem(last=False)
        return out

    def clear(self) -> None:
        """Forgets every result."""
        with self._lock:
            self._kept.clear()

    def __len__(self) -> int:
        return len(self._kept)


_MISSING = object()
