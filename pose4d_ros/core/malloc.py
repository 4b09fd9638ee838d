"""How the C heap serves large blocks: from memory the process keeps, not fresh pages each time.

glibc's malloc maps a block over its mmap threshold (128 KB at start, raised dynamically up to
32 MB as such blocks are freed) with a fresh `mmap` and unmaps it on free, and gives the top of
the heap back to the kernel beyond its trim threshold. A camera frame is such a block several
times over: the DDS reader's buffer, the Python bytes rclpy takes, each array decoded from it
and each full-image temporary of the stages. Every fresh mapping is zeroed page by page on
first touch: a 640x480 colour frame received by a subscriber that does nothing with it cost
2.5 ms CPU, 0.67 ms with the blocks kept (perf: page faults and `clear_page_erms` were half of
it). `keep_freed_memory()` sets the mmap threshold to `MMAP_THRESHOLD` and the trim threshold
to `TRIM_THRESHOLD` (mallopt), so freed frames are reused; the process's resident size stays
at its peak working set instead of following each frame down and up again.

Every node calls it before it starts (`nodes.common.run`), and so does the `pose4d` command,
so the offline core that benchmarks compare against runs with the same heap.
"""

from __future__ import annotations

import ctypes
import ctypes.util

# mallopt parameters (malloc.h)
_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
# blocks up to this size come from the heap (glibc's largest allowed value is 32 MB on 64-bit)
MMAP_THRESHOLD = 32 * 1024 * 1024
# free memory at the heap's top kept up to this size
TRIM_THRESHOLD = 256 * 1024 * 1024


def keep_freed_memory() -> bool:
    """Set glibc's mmap and trim thresholds (see the module docstring); False where the C
    library is not glibc (nothing changed)."""
    name = ctypes.util.find_library('c')
    try:
        libc = ctypes.CDLL(name)
        mallopt = libc.mallopt
    except (OSError, AttributeError, TypeError):
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    return bool(mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD)
                and mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD))
