"""Resident memory that follows the slab, not the number of slabs.

glibc's malloc serves a large request (128 kB at first) from its own mapping, returned to
the system on free, but each time such a block is freed it raises that threshold to the
block's size (up to 32 MB on 64-bit). After the first slab has come and gone, arrays of a
slab's size are carved from the heap instead, whose freed space fragments and is kept: an
out-of-core sweep then grew by about a slab's share for every group it passed (29 → 65 MiB
over one sweep of 10 groups of 50k discs; flat at 27 MiB with the threshold fixed). Setting
the threshold explicitly (mallopt M_MMAP_THRESHOLD) also switches its adjustment off, so
every large array keeps its own mapping and is given back when freed. Elsewhere than glibc
this does nothing. ``import ooc_dem`` fixes it for the whole process: a monolithic run
kept its set-up's freed arrays in the heap too (bed-1000000: 55 B/disc).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import sys

M_TRIM_THRESHOLD = -1  # glibc's malloc.h
M_MMAP_THRESHOLD = -3
MMAP_THRESHOLD_BYTES = 128 * 1024  # glibc's initial value, kept fixed

_done = False


def bound_heap() -> bool:
    """Fix malloc's mmap threshold for this process (once); True where it took effect."""
    global _done
    if _done:
        return True
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):  # not glibc (musl has no mallopt)
        return False
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    ok = mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES) == 1
    # free heap space at the top is given back beyond this (the default, made fixed too)
    ok = mallopt(M_TRIM_THRESHOLD, 2 * MMAP_THRESHOLD_BYTES) == 1 and ok
    _done = ok
    return ok
