"""Frames in, prepared frames out, one step ahead: image decode and seed detection of frame t+1 run in a
background thread while the SLAM core associates frame t (onnxruntime, OpenCV and most numpy kernels release
the GIL, so on two cores the two stages overlap).

* :class:`Prepared` - one frame with its detections (``det``: a matcher's ``detect(frame)`` result, None for
  matchers without a separate detection step) and the wall time of each stage.
* :func:`prepare` - the stage itself: ``load(i)`` then ``matcher.detect(frame)`` when the matcher has one.
* :class:`Prefetch` - iterate over ``work(item)`` for the items of a source with at most ``depth`` results
  waiting (bounded memory); an exception of ``work`` re-raises in the consumer at that item's position, and
  closing the iterator (end of loop, ``break``, Ctrl-C) stops the thread.

The results are identical to running the two stages one after the other: detection of a frame depends on that
frame alone (the detector fixes its input scale on the first frame, before the second is prepared).
"""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from typing import Any

from seedmap.records import StereoFrame

#: how often (s) a blocked producer checks whether the consumer went away
_POLL_S = 0.05


@dataclass
class Prepared:
    """One frame ready for the matcher's association: images, detections (or None) and stage times (ms)."""

    frame: StereoFrame
    det: Any = None
    timings_ms: dict[str, float] = field(default_factory=dict)


def prepare(load: Callable[[Any], StereoFrame], detect: Callable[[StereoFrame], Any] | None) -> Callable[[Any], Prepared]:
    """``work(key) -> Prepared``: ``load(key)`` (the decoded stereo pair), then ``detect(frame)`` if given."""

    def work(key: Any) -> Prepared:
        t0 = time.perf_counter()
        frame = load(key)
        t1 = time.perf_counter()
        tm = {"load": (t1 - t0) * 1e3}
        det = None
        if detect is not None:
            det = detect(frame)
            tm["detect"] = (time.perf_counter() - t1) * 1e3
        return Prepared(frame, det, tm)

    return work


class _Failed:
    __slots__ = ("exc",)

    def __init__(self, exc: BaseException) -> None:
        self.exc = exc


_END = object()


class Prefetch:
    """``for out in Prefetch(work, items, depth): ...`` yields ``work(item)`` in order, computed ahead in one
    daemon thread. ``depth`` = 0 runs ``work`` inline (no thread). ``stop``: an event that, once set, ends the
    iteration at the next item (the items prepared ahead are dropped)."""

    def __init__(self, work: Callable[[Any], Any], items: Iterable[Any], depth: int = 1,
                 stop: threading.Event | None = None) -> None:
        self.work = work
        self.items = items
        self.depth = max(0, int(depth))
        self._stop = stop if stop is not None else threading.Event()
        self._thread: threading.Thread | None = None

    def _put(self, q: queue.Queue, x: Any) -> bool:
        while not self._stop.is_set():
            try:
                q.put(x, timeout=_POLL_S)
                return True
            except queue.Full:
                continue
        return False

    def _produce(self, q: queue.Queue) -> None:
        try:
            for item in self.items:
                if self._stop.is_set():
                    return
                try:
                    out = self.work(item)
                except BaseException as e:  # handed to the consumer, which raises it at this item
                    self._put(q, _Failed(e))
                    return
                if not self._put(q, out):
                    return
        except BaseException as e:  # the source itself failed
            self._put(q, _Failed(e))
            return
        self._put(q, _END)

    def __iter__(self) -> Iterator[Any]:
        if self.depth == 0:
            for item in self.items:
                if self._stop.is_set():
                    return
                yield self.work(item)
            return
        q: queue.Queue = queue.Queue(maxsize=self.depth)
        self._thread = threading.Thread(target=self._produce, args=(q,), name="seedmap-prefetch", daemon=True)
        self._thread.start()
        try:
            while not self._stop.is_set():
                try:
                    x = q.get(timeout=_POLL_S)
                except queue.Empty:
                    if self._stop.is_set():
                        return
                    continue
                if x is _END:
                    return
                if isinstance(x, _Failed):
                    raise x.exc
                yield x
        finally:
            self.close()

    def close(self) -> None:
        """Stop the producer (it finishes the item in progress, then exits)."""
        self._stop.set()
        t = self._thread
        if t is not None and t is not threading.current_thread():
            t.join(timeout=30.0)
