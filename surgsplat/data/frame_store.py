"""Frame pixels decoded from a scene's files on demand, so that memory does not grow with the
length of the clip.

A FrameStore keeps the most recently used frames in a cache bounded in bytes (least recently
used out first) and decodes every other frame on one background thread: `prefetch(index)` starts
decoding a frame that will be needed soon, `get(index)` returns a frame, waiting for its decode
when it is not cached. Decoding errors (a DataError naming the file) reach the caller of `get`.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field

from torch import Tensor

CACHE_BYTES = 512 * 2**20
"""Default bound of a scene's frame cache: 512 MiB (about 70 frames of 854x480 with depth)."""
MIN_CACHED_FRAMES = 8
"""The cache holds at least this many frames whatever their size, so prefetched frames are not
evicted before they are used."""


@dataclass(frozen=True)
class FramePixels:
    """What a frame's files hold, decoded."""

    image: Tensor  # [H, W, 3] float32 RGB in [0, 1]
    depth: Tensor | None  # [H, W] float32 in the scene's depth unit; 0 = no depth
    tool: Tensor  # [H, W] bool, True = tool
    fov: Tensor  # [H, W] bool, True = inside the field of view
    tissue: Tensor = field(init=False)  # [H, W] bool, True = tissue = fov & ~tool

    def __post_init__(self) -> None:
        object.__setattr__(self, "tissue", self.fov & ~self.tool)

    @property
    def nbytes(self) -> int:
        """Bytes held by the tensors this frame owns (the shared fov mask excluded)."""
        owned = [self.image, self.tool, self.tissue] + ([self.depth] if self.depth is not None
                                                        else [])
        return sum(t.numel() * t.element_size() for t in owned)


class FrameStore:
    """Frames 0..N-1 of one scene, decoded by `decode(index)` when needed, with a bounded cache
    and a background prefetch; see the module docstring. Thread-safe."""

    def __init__(self, decode: Callable[[int], FramePixels], cache_bytes: int = CACHE_BYTES):
        self._decode = decode
        self.cache_bytes = cache_bytes
        self._cache: OrderedDict[int, FramePixels] = OrderedDict()
        self._cached_bytes = 0
        self._pending: dict[int, Future] = {}
        self._lock = threading.Lock()
        self._executor: ThreadPoolExecutor | None = None

    def __len__(self) -> int:
        return len(self._cache)

    def put(self, index: int, pixels: FramePixels) -> None:
        """Cache frame `index` (e.g. decoded while the scene was validated)."""
        with self._lock:
            self._insert(index, pixels)

    def get(self, index: int) -> FramePixels:
        """Frame `index`'s pixels: from the cache, else decoded (on the store's thread)."""
        with self._lock:
            pixels = self._cache.get(index)
            if pixels is not None:
                self._cache.move_to_end(index)
                return pixels
        future = self._submit(index)
        try:
            return future.result()
        finally:
            with self._lock:
                if self._pending.get(index) is future:
                    del self._pending[index]

    def prefetch(self, index: int) -> None:
        """Start decoding frame `index` in the background unless it is cached or under way."""
        with self._lock:
            if index in self._cache:
                return
        self._submit(index)

    def is_cached(self, index: int) -> bool:
        with self._lock:
            return index in self._cache

    def _submit(self, index: int) -> Future:
        with self._lock:
            future = self._pending.get(index)
            if future is None:
                if self._executor is None:
                    self._executor = ThreadPoolExecutor(max_workers=1,
                                                        thread_name_prefix="frame-decode")
                future = self._executor.submit(self._load, index)
                self._pending[index] = future
            return future

    def _load(self, index: int) -> FramePixels:
        """Decode frame `index` and cache it (runs on the store's thread)."""
        pixels = self._decode(index)
        with self._lock:
            self._insert(index, pixels)
            self._pending.pop(index, None)
        return pixels

    def _insert(self, index: int, pixels: FramePixels) -> None:
        """Cache `pixels` as the most recent entry, evicting the oldest beyond the bound (the
        caller holds the lock)."""
        previous = self._cache.pop(index, None)
        if previous is not None:
            self._cached_bytes -= previous.nbytes
        self._cache[index] = pixels
        self._cached_bytes += pixels.nbytes
        while (len(self._cache) > MIN_CACHED_FRAMES
               and self._cached_bytes > self.cache_bytes):
            _, evicted = self._cache.popitem(last=False)
            self._cached_bytes -= evicted.nbytes
