"""A process's heap: memory freed given back to the system between a report's steps, the
objects that live through a whole report or summary kept out of the cyclic garbage
collector's passes, and the collector paused while many objects and no garbage are made."""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import functools
import gc
from collections.abc import Callable, Iterator


@functools.cache
def _libc() -> ctypes.CDLL | None:
    """The C library when it is glibc (it has ``malloc_trim``), else None."""
    name = ctypes.util.find_library("c")
    libc = ctypes.CDLL(name) if name else None
    return libc if libc is not None and hasattr(libc, "malloc_trim") else None


def release_freed_memory() -> None:
    """Give the heap memory freed since to the system (glibc's ``malloc_trim``: glibc keeps
    the freed pages of many small allocations; ``grand`` 0–18's report peaks 0.1–0.2 GB lower
    with it after each step). Costs milliseconds; a no-op without glibc. Arrow's memory pool
    is left alone: releasing it after each step (``release_unused``) raised the peak by
    0.4 GB."""
    libc = _libc()
    if libc is not None:
        libc.malloc_trim(0)


def freeze_alive(collect: bool = True) -> None:
    """Move every object alive now out of the cyclic garbage collector's passes
    (:func:`gc.freeze`: for good, or until :func:`gc.unfreeze`), after a full collection
    (``collect``) so that garbage already made is freed, not kept. A process calls it once
    what it holds lives as long as it (docs/architecture.md)."""
    if collect:
        gc.collect()
    gc.freeze()


@contextlib.contextmanager
def long_lived(collect: bool = True) -> Iterator[Callable[[], None]]:
    """A block given a function that moves every object alive when it is called out of the
    cyclic garbage collector's passes (:func:`gc.freeze`) until the block ends
    (:func:`gc.unfreeze`: collected as any from then on). A report calls it once its sweeps
    are loaded, a sweep's summary once its records are listed: they live to the end, and each
    full collection walked them again (``grand`` 0–18's report: 1.44 → 0.54 s of
    collections; its summary: 0.1 s a collection). ``collect``: garbage made before the call
    freed first (a full collection), else kept with the rest until the block ends. When the
    process held frozen objects before the block (the warm server's preloaded stack, frozen
    in every command it forks), what the block froze stays frozen after it: the two cannot be
    told apart (objects no longer used are freed by their reference counts all the same; only
    garbage in reference cycles waits)."""
    owned = gc.get_freeze_count() == 0
    try:
        yield lambda: freeze_alive(collect)
    finally:
        if owned:
            gc.unfreeze()


@contextlib.contextmanager
def collection_paused() -> Iterator[None]:
    """The cyclic garbage collector off in the block (as it was after): listing 40,320 run
    records makes a million containers and no garbage, and the collections their count set
    off walked every object of the process (full ones: 0.1 s each in a ``grand`` summary)."""
    was = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was:
            gc.enable()
