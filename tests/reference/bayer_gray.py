#!/usr/bin/env python3
"""Reference for capture::convert::bayer8: a smooth colour scene, its RGGB mosaic and its true
luma from OpenCV (cv2.cvtColor RGB2GRAY, BT.601). Writes tests/data/bayer/.

Run from the crate root: python3 tests/reference/bayer_gray.py
"""
import os

import cv2
import numpy as np

W, H = 64, 48
out = os.path.join(os.path.dirname(__file__), "..", "data", "bayer")
os.makedirs(out, exist_ok=True)

y, x = np.mgrid[0:H, 0:W].astype(np.float64)
# Smooth, distinct channels (low spatial frequency so a 3x3 footprint barely blurs them).
r = 128 + 100 * np.sin(x / 11.0 + 0.3)
g = 128 + 90 * np.cos(y / 9.0 - 0.5)
b = 60 + 50 * np.sin((x + y) / 14.0)
rgb = np.clip(np.rint(np.dstack([r, g, b])), 0, 255).astype(np.uint8)

# RGGB: R at (even x, even y), B at (odd x, odd y), G elsewhere.
mosaic = np.empty((H, W), np.uint8)
mosaic[0::2, 0::2] = rgb[0::2, 0::2, 0]
mosaic[0::2, 1::2] = rgb[0::2, 1::2, 1]
mosaic[1::2, 0::2] = rgb[1::2, 0::2, 1]
mosaic[1::2, 1::2] = rgb[1::2, 1::2, 2]
mosaic.tofile(os.path.join(out, f"scene_rggb_{W}x{H}.raw"))

luma = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
cv2.imwrite(os.path.join(out, f"scene_luma_{W}x{H}.png"), luma)
print("wrote", out, "opencv", cv2.__version__)
