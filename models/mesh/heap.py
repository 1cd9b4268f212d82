"""The reading process's heap kept between reads (issue 23: the sandboxed read's speed).

A read of 10^5 cells allocates some 30 MB in the caller (the arrays copied from the reading child,
the Mesh's measures and centroids, the checks' temporaries) and frees most of it when the next
read comes. glibc's malloc hands blocks above its mmap threshold to fresh mappings and trims the
top of its heap when the free space there passes its trim threshold, so every read met its memory
again as new pages: one page fault per 4 KiB touched, 1,300-2,000 faults per 10^5-cell read,
~135-500 per 10^4-cell one, each costing about a microsecond on this kind of machine (a virtual
one): 15-30% of a sandboxed read. `keep` tells malloc, once per process, to serve blocks up to
MMAP_THRESHOLD from its heap (glibc's own dynamic threshold stops at the same 32 MiB on 64-bit
systems) and to keep TOP_PAD at the heap's top when it trims, so a read reuses the pages of the one
before. The cost: up to TOP_PAD (64 MiB) of freed memory the process keeps instead of returning
it. Applied by `sandbox.read_mesh_safe` (the service, the workers, the CLI, the Python API), its
in-process reads too; MAGNET_READ_HEAP=0 leaves malloc as it is. Only glibc has `mallopt`: elsewhere nothing changes.
"""

from __future__ import annotations

import os

MMAP_THRESHOLD = 32 << 20  # M_MMAP_THRESHOLD: blocks up to this from the heap
TOP_PAD = 64 << 20  # M_TOP_PAD: kept at the heap's top when it trims (and added when it grows)
_M_TOP_PAD, _M_MMAP_THRESHOLD = -2, -3  # glibc's malloc.h

_kept: bool | None = None


def keep() -> bool:
    """Once per process: glibc's malloc keeps its heap between reads (the module docstring). True
    when applied (now or before), False where it is not glibc, mallopt refused, or
    MAGNET_READ_HEAP=0."""
    global _kept
    if _kept is None:
        _kept = False
        if os.environ.get("MAGNET_READ_HEAP", "1") != "0":
            try:
                import ctypes

                mallopt = ctypes.CDLL(None).mallopt
                mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
                gnu = bool(ctypes.CDLL(None).gnu_get_libc_version)  # musl's mallopt does nothing
                _kept = (
                    gnu
                    and mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD) == 1
                    and mallopt(_M_TOP_PAD, TOP_PAD) == 1
                )
            except (OSError, AttributeError):
                _kept = False
    return _kept
