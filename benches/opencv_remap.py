#!/usr/bin/env python3
"""cv2.remap timing for the `remap` criterion bench (benches/remap.rs): same 2448x2048 gray
frame size, same fisheye->perspective map (cv::fisheye model, f = 640 px, no distortion, virtual
pinhole f = 700 px), INTER_LINEAR, BORDER_CONSTANT 0, with 1 and 2 OpenCV threads.

Times cv2.remap with the CV_32FC1 float maps (what the Rust fixed-point path is compared against)
and, for reference, with maps pre-converted by cv2.convertMaps to CV_16SC2 fixed point.
Prints the median and the best of N runs in milliseconds.

Run: python3 benches/opencv_remap.py
"""
import time

import cv2
import numpy as np

W, H = 2448, 2048
RUNS = 60


def main():
    k = np.array([[640.0, 0.0, 1224.0], [0.0, 640.0, 1024.0], [0.0, 0.0, 1.0]])
    p = np.array([[700.0, 0.0, 1224.0], [0.0, 700.0, 1024.0], [0.0, 0.0, 1.0]])
    mx, my = cv2.fisheye.initUndistortRectifyMap(k, np.zeros((4, 1)), np.eye(3), p, (W, H),
                                                 cv2.CV_32FC1)
    img = np.random.default_rng(7).integers(0, 256, (H, W), dtype=np.uint8)
    fx, fy = cv2.convertMaps(mx, my, cv2.CV_16SC2)
    out = np.empty_like(img)
    print(f"OpenCV {cv2.__version__}, {W}x{H}, {RUNS} runs each")
    for threads in (1, 2):
        cv2.setNumThreads(threads)
        for name, a, b in (("float_maps", mx, my), ("fixed_maps", fx, fy)):
            for _ in range(5):
                cv2.remap(img, a, b, cv2.INTER_LINEAR, dst=out, borderMode=cv2.BORDER_CONSTANT)
            t = []
            for _ in range(RUNS):
                t0 = time.perf_counter()
                cv2.remap(img, a, b, cv2.INTER_LINEAR, dst=out, borderMode=cv2.BORDER_CONSTANT)
                t.append(time.perf_counter() - t0)
            t = np.array(t) * 1e3
            print(f"cv2.remap {name} threads={threads}: median {np.median(t):.2f} ms, "
                  f"best {t.min():.2f} ms")


if __name__ == "__main__":
    main()
