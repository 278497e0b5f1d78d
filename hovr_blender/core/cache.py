"""One small least-recently-used cache, for what is expensive to make and cheap to keep a few
of: loaded meshes, meshes uploaded to a device, field samples."""
from __future__ import annotations

from collections import OrderedDict
from typing import Callable, Hashable


class LRUCache:
    """At most `size` values by key; the least recently used goes first."""

    def __init__(self, size: int):
        self.size = int(size)
        self._items: OrderedDict = OrderedDict()

    def get(self, key: Hashable, make: Callable[[], object] | None = None):
        """The value for key (now the most recent); if absent, make() is stored and returned
        (None without `make`)."""
        if key in self._items:
            self._items.move_to_end(key)
            return self._items[key]
        if make is None:
            return None
        value = make()
        self.put(key, value)
        return value

    def put(self, key: Hashable, value) -> None:
        self._items[key] = value
        self._items.move_to_end(key)
        while len(self._items) > self.size:
            self._items.popitem(last=False)

    def items(self):
        return list(self._items.items())

    def values(self):
        return list(self._items.values())

    def __contains__(self, key) -> bool:
        return key in self._items

    def __len__(self) -> int:
        return len(self._items)

    def clear(self) -> None:
        self._items.clear()
