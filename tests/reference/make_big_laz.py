#!/usr/bin/env python3
"""A synthetic LAZ of at least 1 GB for the `tile build` memory benchmark (docs/benchmarks.md).

Usage: make_big_laz.py OUT.laz [MIN_BYTES]

A 500 m x 500 m street survey (ETRS89 / UTM 32N): sloping ground (LAS class 2) with random 16-bit
intensity and RGB (which compress poorly, so the file is big for its point count), plus box-shaped
objects (class 1). Written by laspy + lazrs in chunks of 4 M points until the file holds MIN_BYTES
(default 1.05e9). Seeded: the same file every run.
"""
import os
import sys

import laspy
import numpy as np
import pyproj

out = sys.argv[1]
min_bytes = float(sys.argv[2]) if len(sys.argv) > 2 else 1.05e9
rng = np.random.default_rng(7)
X0, Y0, SIZE, CHUNK = 690_000.0, 5_335_000.0, 500.0, 4_000_000

header = laspy.LasHeader(point_format=7, version="1.4")
header.scales = np.array([0.001, 0.001, 0.001])
header.offsets = np.array([X0, Y0, 500.0])
header.add_crs(pyproj.CRS.from_epsg(25832))
total = 0
with laspy.open(out, mode="w", header=header, do_compress=True) as w:
    while os.path.getsize(out) < min_bytes:
        x = X0 + rng.uniform(0, SIZE, CHUNK)
        y = Y0 + rng.uniform(0, SIZE, CHUNK)
        z = 520.0 + 0.02 * (x - X0) + 0.01 * (y - Y0) + rng.normal(0, 0.01, CHUNK)
        cls = np.full(CHUNK, 2, np.uint8)
        obj = rng.uniform(0, 1, CHUNK) < 0.1
        z[obj] += rng.uniform(0.3, 3.0, obj.sum())
        cls[obj] = 1
        p = laspy.ScaleAwarePointRecord.zeros(CHUNK, header=header)
        p.x, p.y, p.z = x, y, z
        p.intensity = rng.integers(1, 65535, CHUNK, dtype=np.uint16)
        p.classification = cls
        p.red = rng.integers(0, 65535, CHUNK, dtype=np.uint16)
        p.green = rng.integers(0, 65535, CHUNK, dtype=np.uint16)
        p.blue = rng.integers(0, 65535, CHUNK, dtype=np.uint16)
        w.write_points(p)
        total += CHUNK
print(f"{out}: {total} points, {os.path.getsize(out) / 1e9:.2f} GB")
