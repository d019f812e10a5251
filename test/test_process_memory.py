"""herd_ros.process_memory: a command keeps the memory it freed (no new page faults when it
allocates again what it just dropped); HERD_ROS_MALLOC=default leaves glibc's defaults."""
import os
import subprocess
import sys

import pytest

# allocate and touch 64 MiB, drop it, allocate and touch it again: the page faults of the
# second time (a kept heap reuses the pages; a fresh mmap faults every one of them in)
SCRIPT = r'''
import resource, sys
import numpy as np
from herd_ros.process_memory import keep_freed_memory
kept = keep_freed_memory() if sys.argv[1] == 'keep' else False
a = np.ones(8 << 20); del a
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
a = np.ones(8 << 20)
print(kept, resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
'''


def _faults(mode, **env):
    out = subprocess.run([sys.executable, '-c', SCRIPT, mode], capture_output=True, text=True,
                         check=True, env={**os.environ, **env}).stdout.split()
    return out[0] == 'True', int(out[1])


@pytest.mark.skipif(not sys.platform.startswith('linux'), reason='glibc malloc only')
def test_freed_memory_is_reused_without_page_faults():
    fresh = (64 << 20) // (2 << 20)     # the fewest faults of a fresh mapping: 2 MiB pages
    kept, faults = _faults('keep')
    assert kept
    assert faults < 8                            # the freed pages, reused
    kept, faults = _faults('defaults')
    assert not kept
    assert faults >= fresh                       # glibc's default: a new mapping
    kept, faults = _faults('keep', HERD_ROS_MALLOC='default')
    assert not kept and faults >= fresh
