"""The CPUs this process may run on (its affinity mask, e.g. under ``taskset`` or a container's
cpuset): the number of threads worth starting for work that releases the GIL."""
from __future__ import annotations

import os


def usable_cpus() -> int:
    """CPUs this process may be scheduled on (os.cpu_count() where the mask is not known), at least 1."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)
