"""Keeps numba's on-disk cache of the package's compiled kernels (``@njit(cache=True)``, written to the
``__pycache__`` folders beside the sources) from serving stale code.

numba checks a cached kernel against its own source file only: a change to a function it calls from
another file goes unnoticed (numba's documented cache limitation), and the cached caller keeps the old
callee compiled into it. Editing ``methods/qp/_qp_kernels.py`` left ``_daqp_kernels.solve_rows`` running the
previous ``working_set_answer``, 6e-9 m/s off in velocity, until its cache was deleted by hand; a
``git pull`` into an editable install does the same to a user. So the package stamps its cache with a
digest of every file that compiled code comes from, and drops all its cached kernels when the digest
changes (:func:`drop_stale`, called once at import, before any kernel is loaded).

:class:`CompileClock` times what the kernels cost before they step: numba compiling them (a first run, or
after a change) or loading them from this cache, so that a run can report its stepping speed apart from it.
"""
from __future__ import annotations

import hashlib
import time
from pathlib import Path

from numba.core import event

__all__ = ["CompileClock", "drop_stale", "sources_digest"]

PACKAGE = Path(__file__).resolve().parent
STAMP = "kernel_sources.sha256"


def _sources(root: Path) -> list[Path]:
    """The files compiled code is built from: the kernel modules and the C-call intrinsics."""
    return sorted([*root.rglob("_*kernels.py"), *root.rglob("_c_calls.py")])


def sources_digest(root: Path = PACKAGE) -> str:
    """SHA-256 over the relative paths and contents of the kernel sources below ``root``."""
    digest = hashlib.sha256()
    for path in _sources(root):
        digest.update(str(path.relative_to(root)).encode() + b"\0" + path.read_bytes() + b"\0")
    return digest.hexdigest()


def drop_stale(root: Path = PACKAGE) -> bool:
    """Delete every cached kernel (``*.nbi``, ``*.nbc``) below ``root`` when the kernel sources' digest
    differs from the stamp in ``root/__pycache__`` (or there is none), then write the stamp. Returns
    whether anything was dropped. A read-only install (numba then caches elsewhere) is left alone."""
    stamp = root / "__pycache__" / STAMP
    digest = sources_digest(root)
    try:
        if stamp.read_text() == digest:
            return False
    except OSError:
        pass
    try:
        stale = [*root.rglob("*.nbi"), *root.rglob("*.nbc")]
        for path in stale:
            path.unlink(missing_ok=True)
        stamp.parent.mkdir(exist_ok=True)
        stamp.write_text(digest)
    except OSError:
        return False
    return bool(stale)


class CompileClock(event.Listener):
    """While entered: the seconds this process spends getting compiled kernels ready, ``seconds`` (numba's
    compiler lock held: compiling, or loading from the on-disk cache; nested holds counted once) and of
    those ``compiling`` (numba's compiler itself ran: the cache had no valid copy). A hold still open counts
    up to now, so ``seconds`` read before and after a stretch of stepping gives the part spent in it."""

    def __init__(self):
        self._done = {"numba:compiler_lock": 0.0, "numba:compile": 0.0}
        self._open: dict[str, tuple[int, float]] = {}

    def on_start(self, ev) -> None:
        depth, since = self._open.get(ev.kind, (0, time.perf_counter()))
        self._open[ev.kind] = (depth + 1, since)

    def on_end(self, ev) -> None:
        depth, since = self._open.pop(ev.kind)
        if depth > 1:
            self._open[ev.kind] = (depth - 1, since)
        else:
            self._done[ev.kind] += time.perf_counter() - since

    def _total(self, kind: str) -> float:
        depth_since = self._open.get(kind)
        return self._done[kind] + (time.perf_counter() - depth_since[1] if depth_since else 0.0)

    @property
    def seconds(self) -> float:
        return self._total("numba:compiler_lock")

    @property
    def compiling(self) -> float:
        return self._total("numba:compile")

    def __enter__(self) -> CompileClock:
        for kind in self._done:
            event.register(kind, self)
        return self

    def __exit__(self, *exc) -> None:
        for kind in self._done:
            event.unregister(kind, self)
