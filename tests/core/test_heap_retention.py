"""While a stage runs, the heap memory it freed goes back to the operating system (core/pipeline.py)."""

import ctypes
import sys
import time

import numpy as np
import pytest

from stratamap.core.pipeline import MemorySampler, release_free_memory, resident_mb


def _glibc() -> bool:
    try:
        return hasattr(ctypes.CDLL("libc.so.6"), "malloc_trim")
    except OSError:
        return False


def _fragmented_heap() -> tuple[list, float, float]:
    """1 MiB buffers served from the heap, each followed by a small long-lived object, then freed:
    glibc keeps the freed buffers resident (the small objects stop the heap from shrinking)."""
    big = np.ones(16 * 2**20, np.uint8)  # freed, it raises glibc's mapping threshold past 1 MiB
    del big
    release_free_memory()
    before = resident_mb()
    frames, pins = [], []
    for _ in range(160):
        frames.append(np.ones(2**20, np.uint8))
        pins.append(bytearray(4096))
    assert resident_mb() - before > 120
    del frames
    return pins, before, resident_mb()


@pytest.mark.skipif(not sys.platform.startswith("linux") or not _glibc(), reason="glibc's malloc_trim only")
def test_freed_frame_buffers_leave_the_resident_memory_while_a_stage_runs():
    # (Run alone with release_every=None, the freed buffers stay resident: 160 MB here.)
    with MemorySampler(interval=0.02, release_every=0.2):
        pins, before, _ = _fragmented_heap()
        time.sleep(0.6)
        after = resident_mb()
    assert after - before < 40, f"{after - before:.0f} MB of freed buffers still resident"
    del pins
