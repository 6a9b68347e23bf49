"""A batch's copies in contiguous blocks, one per core, walked by a compiled kernel on threads (the elastic
batch's free step, ``elastic/batch.ElasticBatch.advance``, and its member-contact detection,
``contact/detection.CompiledDetector.walk``).

The copies of a batch are independent and the batch kernels do the same operations on each copy, so a kernel
called on a block of copies gives each copy the very numbers it gives it in the whole batch. A kernel compiled
with ``nogil=True`` runs its blocks side by side on Python threads; each block is copied into arrays of its own
(the copy axis last and contiguous, the layout the kernels are compiled and vectorised for) and its results
written back.
"""
from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from functools import cache

import numba

# the fewest copies worth a thread of their own: below it the block's copies-innermost loops are too short
MIN_BLOCK = 256


def copy_blocks(copies: int) -> list[slice]:
    """Contiguous blocks of ``copies``, at most one per core (numba's thread count), none under ``MIN_BLOCK``."""
    if copies < 2 * MIN_BLOCK:   # one block (a Simulator's single copy asks every step: no thread-count query)
        return [slice(0, copies)]
    count = max(1, min(numba.get_num_threads(), copies // MIN_BLOCK))
    edges = [copies * i // count for i in range(count + 1)]
    return [slice(a, b) for a, b in zip(edges[:-1], edges[1:])]


@cache
def _pool(workers: int) -> ThreadPoolExecutor:
    return ThreadPoolExecutor(max_workers=workers, thread_name_prefix="tensegrity_sim-copies")


def on_blocks(run, blocks: list[slice]) -> list:
    """``run(block)`` for each block, side by side on threads (``run`` calls a ``nogil`` kernel); the results
    in the blocks' order. One block runs here."""
    if len(blocks) == 1:
        return [run(blocks[0])]
    return list(_pool(len(blocks)).map(run, blocks))
