"""Keeps numba's on-disk cache of the package's compiled kernels (``@njit(cache=True)``, written to the
``__pycache__`` folders beside the sources) from serving stale code.

numba checks a cached kernel against its own source file only: a change to a function it calls from
another file goes unnoticed (numba's documented cache limitation), and the cached caller keeps the old
callee compiled into it. Editing ``methods/qp/_qp_kernels.py`` left ``_daqp_kernels.solve_rows`` running the
previous ``working_set_answer``, 6e-9 m/s off in velocity, until its cache was deleted by hand; a
``git pull`` into an editable install does the same to a user. So the package stamps its cache with a
digest of every file that compiled code comes from, and drops all its cached kernels when the digest
changes (:func:`drop_stale`, called once at import, before any kernel is loaded).
"""
from __future__ import annotations

import hashlib
from pathlib import Path

__all__ = ["drop_stale", "sources_digest"]

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
