"""Read ahead: the next frames are read and decoded in a background thread while the caller works.

Reading a frame (decompressing its chunk, parsing the messages, making the arrays) is a few
milliseconds, much of it outside the GIL (zstd and lz4 release it), so on a machine with a core
to spare it overlaps the NDF's encoding of the frame before. On a machine without one it costs
nothing but a thread switch. The order of the items, and every exception, reach the caller as if
it had iterated itself; a caller that stops early stops the thread too.
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Iterator
from typing import TypeVar

T = TypeVar("T")

_DONE = object()  # the producer has no more items
_POLL_S = 0.1     # how often a blocked producer looks whether the caller has gone


def prefetched(items: Iterator[T], depth: int = 4) -> Iterator[T]:
    """`items`, produced up to `depth` ahead in a daemon thread. `depth` 0: `items` as they are."""
    if depth <= 0:
        yield from items
        return
    ready: queue.Queue = queue.Queue(maxsize=depth)
    stop = threading.Event()

    def produce() -> None:
        try:
            for item in items:
                if not _put(ready, (item, None), stop):
                    return
            _put(ready, (_DONE, None), stop)
        except BaseException as error:  # handed to the caller, which raises it
            _put(ready, (_DONE, error), stop)
        finally:
            close = getattr(items, "close", None)
            if close is not None:
                close()  # a generator's finally blocks (open files) run in this thread

    thread = threading.Thread(target=produce, name="ndfa-prefetch", daemon=True)
    thread.start()
    try:
        while True:
            item, error = ready.get()
            if error is not None:
                raise error
            if item is _DONE:
                return
            yield item
    finally:
        stop.set()
        thread.join()


def _put(ready: queue.Queue, entry: tuple, stop: threading.Event) -> bool:
    """Put `entry`, waiting while the queue is full; False when the caller stopped listening."""
    while not stop.is_set():
        try:
            ready.put(entry, timeout=_POLL_S)
            return True
        except queue.Full:
            continue
    return False
