#!/usr/bin/env python3
"""Cross-check a simulated scene's truth.json with OpenCV (independent of infraloc's camera code).

Usage: python3 tests/reference/check_sim_truth_opencv.py DIR/truth.json
Projects every control point's map position with cv2.omnidir.projectPoints (Mei) or
cv2.fisheye.projectPoints (equidistant; valid for points in front of the camera) using the true
pose and intrinsics from the file, and prints the largest difference to the stored pixels.
"""
import json
import sys

import cv2
import numpy as np

t = json.load(open(sys.argv[1]))
i = t["intrinsics"]
R = np.array(t["rotation_cam_from_map"])
tv = np.array(t["translation_cam_from_map"])
pts = np.array([c["map"] for c in t["control_points"]], dtype=np.float64)
px = np.array([c["pixel"] for c in t["control_points"]])
# X_c = R X + t = R (X - o) + (t + R o): subtract a common origin so UTM magnitudes cost no precision.
o = pts.mean(0)
rvec, _ = cv2.Rodrigues(R)
tt = (tv + R @ o).reshape(3, 1)
obj = (pts - o).reshape(-1, 1, 3)
if i["model"] == "mei":
    K = np.array([[i["fx"], i["skew"], i["cx"]], [0, i["fy"], i["cy"]], [0, 0, 1]])
    D = np.array([[i["k1"], i["k2"], i["p1"], i["p2"]]])
    img, _ = cv2.omnidir.projectPoints(obj, rvec, tt, K, float(i["xi"]), D)
else:
    K = np.array([[i["fx"], 0, i["cx"]], [0, i["fy"], i["cy"]], [0, 0, 1]])
    D = np.array([i["k1"], i["k2"], i["k3"], i["k4"]])
    img, _ = cv2.fisheye.projectPoints(obj, rvec, tt, K, D, alpha=i.get("alpha", 0.0))
err = np.abs(img.reshape(-1, 2) - px).max()
print(f"{len(px)} control points, max |OpenCV - truth| = {err:.3e} px")
sys.exit(0 if err < 0.01 else 1)
