"""glibc's malloc settings (pipeline/memory.py): a pool worker keeps its large arrays in the heap,
for the next pair to reuse, instead of mapping (and faulting in) each one anew."""

import subprocess
import sys

import pytest

_PROBE = """
import ctypes, sys
import numpy as np
from pipeline.memory import keep_freed_memory

class MallInfo2(ctypes.Structure):
    _fields_ = [(name, ctypes.c_size_t) for name in
                ("arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks", "fsmblks", "uordblks", "fordblks",
                 "keepcost")]

libc = ctypes.CDLL("libc.so.6")
libc.mallinfo2.restype = MallInfo2
if sys.argv[1] == "keep":
    assert keep_freed_memory()
a = np.ones(40 << 18, np.float32)       # 40 MB: above glibc's largest dynamic mmap threshold (32 MB)
print(libc.mallinfo2().hblkhd >> 20)    # MB in blocks mapped on their own
"""


def _mapped_mb(mode: str) -> int:
    out = subprocess.run([sys.executable, "-c", _PROBE, mode], capture_output=True, text=True)
    if out.returncode:
        pytest.skip(f"no glibc mallinfo2 here ({out.stderr.strip().splitlines()[-1]})")
    return int(out.stdout.split()[-1])


def test_a_worker_keeps_a_large_array_in_the_heap_and_glibcs_default_maps_it():
    assert _mapped_mb("default") >= 40
    assert _mapped_mb("keep") == 0
