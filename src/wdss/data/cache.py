"""A byte-bounded LRU of decoded frames, one per process.

Decoding a frame's EXR files costs most of a training batch's loading time on a CPU (a 64^2 patch is cut from
a whole decoded 384x216 frame), and a small dataset is read many times per epoch (several patches per frame, the
previous frame for history). Each loader worker keeps the frames it decoded; the whole of ``data/mini`` fits in
a few hundred MB. Entries are read-only arrays: readers copy what they hand on, so nothing downstream can write
into a cached frame.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Hashable, Mapping

import numpy as np

__all__ = ["FrameCache"]


class FrameCache:
    """Least-recently-used ``key -> {name: array}`` within ``max_bytes``; ``max_bytes=0`` keeps nothing.

    The cache is empty after pickling: a loader worker starts with its own, rather than a copy of the main
    process's frames.
    """

    def __init__(self, max_bytes: int) -> None:
        if max_bytes < 0:
            raise ValueError(f"a frame cache needs max_bytes >= 0, got {max_bytes}")
        self.max_bytes = int(max_bytes)
        self.bytes = 0
        self.hits = 0
        self.misses = 0
        self._entries: OrderedDict[Hashable, dict[str, np.ndarray]] = OrderedDict()

    def __len__(self) -> int:
        return len(self._entries)

    def get(self, key: Hashable) -> dict[str, np.ndarray] | None:
        entry = self._entries.get(key)
        if entry is None:
            self.misses += 1
            return None
        self._entries.move_to_end(key)
        self.hits += 1
        return entry

    def put(self, key: Hashable, arrays: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
        """Store ``arrays`` (made read-only) and evict the least recently used entries beyond the budget."""
        entry = {}
        for name, array in arrays.items():
            array.setflags(write=False)
            entry[name] = array
        size = sum(a.nbytes for a in entry.values())
        if size > self.max_bytes:  # larger than the whole budget: not worth evicting everything for
            return entry
        if key in self._entries:
            self.bytes -= sum(a.nbytes for a in self._entries.pop(key).values())
        self._entries[key] = entry
        self.bytes += size
        while self.bytes > self.max_bytes:
            _, evicted = self._entries.popitem(last=False)
            self.bytes -= sum(a.nbytes for a in evicted.values())
        return entry

    def __getstate__(self) -> dict:
        return {"max_bytes": self.max_bytes}

    def __setstate__(self, state: dict) -> None:
        self.__init__(state["max_bytes"])
