"""Load ahead: items (depth PNGs) decoded on background threads while the caller works on earlier ones."""

from __future__ import annotations

from collections import deque
from concurrent.futures import ThreadPoolExecutor
from itertools import islice
from typing import Callable, Iterator, Sequence, TypeVar

T = TypeVar("T")

_END = object()


def prefetched(load: Callable[[int], T], keys: Sequence[int], ahead: int, threads: int = 1
               ) -> Iterator[tuple[int, T]]:
    """``(key, load(key))`` in order, with up to ``ahead`` loads running on ``threads`` background threads.

    PNG decoding (OpenCV) releases the GIL, so on other cores it overlaps with the numpy
    work of the frame being lifted (and, with two threads, with the next frame's decode).
    """
    if not keys:
        return
    with ThreadPoolExecutor(max_workers=threads) as pool:
        todo = iter(keys)
        pending = deque((k, pool.submit(load, k)) for k in islice(todo, ahead))
        while pending:
            key, fut = pending.popleft()
            nxt = next(todo, _END)
            if nxt is not _END:
                pending.append((nxt, pool.submit(load, nxt)))
            yield key, fut.result()
