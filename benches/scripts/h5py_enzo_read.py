#!/usr/bin/env python3
"""h5py's time to read the Density field of every grid of the Enzo snapshot (the baseline of
the `amr_read` criterion bench): median of 50 runs of opening the file and reading the 10
datasets into numpy arrays. Usage: python3 h5py_enzo_read.py [PATH_TO_moving7_0010.cpu0000]"""
import os
import statistics
import sys
import time

import h5py

HERE = os.path.dirname(os.path.abspath(__file__))
PATH = sys.argv[1] if len(sys.argv) > 1 else os.path.join(
    HERE, "../../../shared/data/enzo-moving7/original/moving7_0010.cpu0000")
times = []
for _ in range(50):
    t = time.perf_counter()
    with h5py.File(PATH, "r") as f:
        arrays = [f[f"Grid{i:08d}/Density"][()] for i in range(1, 11)]
    times.append(time.perf_counter() - t)
print(f"h5py: median {statistics.median(times) * 1e3:.3f} ms for {sum(a.size for a in arrays)} cells")
