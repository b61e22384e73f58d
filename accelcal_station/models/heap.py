"""glibc heap settings for block-wise numpy work (the stacked fitters of a lot).

numpy allocates every temporary afresh, and at the stacked fitters' block size many are
0.1-2 MB.  glibc's defaults give such memory back to the kernel (blocks above its mmap
threshold are unmapped when freed, and the heap top is trimmed once more than twice that
is free), so the next block's temporaries fault every page in again: on model 9 that was
5,000 page faults and 40 % of the time of each block of 2,048 boards, and the faults of two
threads serialise on the process's memory map.  Fixed thresholds keep that memory in the
heap for the next block; larger arrays (a whole chunk's columns) are still mapped and
returned.  Only glibc has ``mallopt``; elsewhere this does nothing.
"""
from __future__ import annotations

import ctypes
import sys

_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3  # malloc.h
MMAP_THRESHOLD = 32 << 20  # glibc's largest allowed on 64-bit: blocks below are heap-allocated
TRIM_THRESHOLD = 128 << 20  # free memory kept at the heap top for reuse, at most

_done = False


def keep_block_memory() -> bool:
    """Set glibc's mmap and trim thresholds once per process; True if they are set."""
    global _done
    if _done or not sys.platform.startswith("linux"):
        return _done
    try:
        mallopt = ctypes.CDLL("libc.so.6").mallopt
    except (OSError, AttributeError):  # not glibc (musl, ...): its own allocator policy stands
        return False
    _done = bool(mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD)) and bool(mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD))
    return _done
