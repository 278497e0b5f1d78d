"""One small least-recently-used cache, for what is expensive to make and cheap to keep a few
of: loaded meshes, meshes uploaded to a device, field samples."""
from __future__ import annotations

import threading
from collections import OrderedDict
from typing import Callable, Hashable


class LRUCache:
    """At most `size` values by key; the least recently used goes first. Safe to use from several
    threads: make() runs outside the lock, so two
    threads missing the same key may both make it, and the last one stored stays."""

    def __init__(self, size: int):
        self.size = int(size)
        self._items: OrderedDict = OrderedDict()
        self._lock = threading.Lock()

    def get(self, key: Hashable, make: Callable[[], object] | None = None):
        """The value for key (now the most recent); if absent, make() is stored and returned
        (None without `make`)."""
        with self._lock:
            if key in self._items:
                self._items.move_to_end(key)
                return self._items[key]
        if make is None:
            return None
        value = make()
        self.put(key, value)
        return value

    def put(self, key: Hashable, value) -> None:
        with self._lock:
            self._items[key] = value
            self._items.move_to_end(key)
            while len(self._items) > self.size:
                self._items.popitem(last=False)

    def items(self):
        with self._lock:
            return list(self._items.items())

    def values(self):
        with self._lock:
            return list(self._items.values())

    def __contains__(self, key) -> bool:
        with self._lock:
            return key in self._items

    def __len__(self) -> int:
        with self._lock:
            return len(self._items)

    def clear(self) -> None:
        with self._lock:
            self._items.clear()
