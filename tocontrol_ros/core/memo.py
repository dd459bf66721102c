"""Answers remembered per object, bounded and shared by threads.

A check that costs inverse kinematics (is this point reachable by this model, has it a
configuration clear of this scene) is asked again and again for the same object and the
same arguments while a stream of replans runs: :class:`OwnedMemo` keeps the newest answers.
Its keys hold the owner's ``id``; the owner is kept with its answer, so that id is not
reused while the answer is remembered, and an answer is given only for that same object.
"""

from __future__ import annotations

import collections
import threading
from collections.abc import Hashable
from typing import Any

__all__ = ["OwnedMemo"]


class OwnedMemo:
    """Up to ``size`` answers, each for an owner object and a key, the newest last.

    Parameters
    ----------
    size : int
        How many answers are kept; the least recently used go first.
    """

    def __init__(self, size: int = 256) -> None:
        self._items: collections.OrderedDict = collections.OrderedDict()
        self._size = size
        self._lock = threading.Lock()

    def get(self, owner: object, key: Hashable, default: Any = None) -> Any:
        """The answer remembered for ``owner`` (that object) and ``key``, else ``default``."""
        slot = (id(owner), key)
        with self._lock:
            found = self._items.get(slot)
            if found is None or found[0] is not owner:
                return default
            self._items.move_to_end(slot)
            return found[1]

    def put(self, owner: object, key: Hashable, value: Any) -> None:
        """Remember ``value`` for ``owner`` and ``key`` (dropping the oldest past ``size``)."""
        with self._lock:
            self._items[(id(owner), key)] = (owner, value)
            while len(self._items) > self._size:
                self._items.popitem(last=False)
