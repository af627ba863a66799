#!/usr/bin/env python3
"""A TUMTraf Intersection camera + Ouster frame as `infraloc refine` inputs.

Reads the dev-kit's camera calibration (`projection_from_<lidar>`, the 3×4 P = K·[R|t] from the
LiDAR frame to pixels), decomposes it (RQ) and writes into OUT:

- `camera.yaml`: the pinhole K as the Mei model with ξ = 0 and no distortion (OpenCV FileStorage);
- `pose.json`: the camera's pose in the LiDAR frame (crs LOCAL), the official calibration;
- `reflectivity.csv`: the sweep's points with Ouster's calibrated `reflectivity` channel (0–255);
  the PCD itself carries `intensity` (the return's signal), which `refine --points X.pcd` reads.

Usage: tumtraf_import.py CAMERA_CALIB.json LIDAR.pcd OUT [--lidar s110_lidar_ouster_south]
Needs numpy only.
"""
import argparse
import json
import os
import sys

import numpy as np


def rq(m):
    """RQ decomposition of a 3×3 matrix: m = K·R with K upper triangular, positive diagonal."""
    p = np.flipud(np.eye(3))
    q, r = np.linalg.qr((p @ m).T)
    k = p @ r.T @ p
    rot = p @ q.T
    s = np.diag(np.sign(np.diag(k)))
    k, rot = k @ s, s @ rot
    return k, rot


def read_pcd(path):
    """ASCII PCD → (field names, rows as float array)."""
    with open(path) as f:
        fields, n = None, None
        for line in f:
            key, *rest = line.split()
            if key == "FIELDS":
                fields = rest
            elif key == "POINTS":
                n = int(rest[0])
            elif key == "DATA":
                if rest[0] != "ascii":
                    sys.exit(f"{path}: DATA {rest[0]}: only ascii PCD is read here")
                break
        data = np.loadtxt(f, ndmin=2)
    if fields is None or data.shape != (n, len(fields)):
        sys.exit(f"{path}: header and data disagree")
    return fields, data


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("calib")
    ap.add_argument("pcd")
    ap.add_argument("out")
    ap.add_argument("--lidar", default="s110_lidar_ouster_south")
    a = ap.parse_args()
    cal = json.load(open(a.calib))
    key = f"projection_from_{a.lidar}"
    if key not in cal:
        sys.exit(f"{a.calib}: no key {key}")
    p = np.array(cal[key], dtype=float)
    k, rot = rq(p[:, :3])
    scale = k[2, 2]
    k = k / scale
    t = np.linalg.solve(k, p[:, 3] / scale)
    if np.linalg.det(rot) < 0:
        rot, t = -rot, -t
    # A point in front of the camera has positive depth: P's overall sign is free.
    fields, data = read_pcd(a.pcd)
    xyz = data[:, :3]
    depth = (xyz @ rot.T + t)[:, 2]
    if np.median(depth) < 0:
        rot, t = -rot, -t
    # -R is not a rotation; flip two axes of the camera frame would change K: P's sign is fixed
    # by the scale's sign instead, so check what we have.
    if np.linalg.det(rot) < 0:
        sys.exit("the decomposition did not give a rotation with the points in front")
    os.makedirs(a.out, exist_ok=True)
    w, h = int(cal["image_width"]), int(cal["image_height"])
    fx, s, cx, fy, cy = (float(v) for v in (k[0, 0], k[0, 1], k[0, 2], k[1, 1], k[1, 2]))
    with open(os.path.join(a.out, "camera.yaml"), "w") as f:
        f.write(
            "%YAML:1.0\n---\nmodel: mei\n"
            f"image_width: {w}\nimage_height: {h}\n"
            "camera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n"
            f"   data: [ {fx!r}, {s!r}, {cx!r}, 0., {fy!r}, {cy!r}, 0., 0., 1. ]\n"
            "distortion_coefficients: !!opencv-matrix\n   rows: 1\n   cols: 4\n   dt: d\n"
            "   data: [ 0., 0., 0., 0. ]\n"
            "xi: !!opencv-matrix\n   rows: 1\n   cols: 1\n   dt: d\n   data: [ 0. ]\n"
        )
    pose = {
        "schema": "infraloc.pose.v1",
        "crs": "LOCAL",
        "rotation_cam_from_map": rot.tolist(),
        "translation_cam_from_map": t.tolist(),
    }
    json.dump(pose, open(os.path.join(a.out, "pose.json"), "w"), indent=2)
    ir = fields.index("reflectivity")
    with open(os.path.join(a.out, "reflectivity.csv"), "w") as f:
        f.write("x,y,z,reflectivity\n")
        for row in data:
            f.write(f"{float(row[0])!r},{float(row[1])!r},{float(row[2])!r},{min(int(row[ir]), 255)}\n")
    c = -rot.T @ t
    print(
        f"K fx {fx:.1f} fy {fy:.1f} skew {s:.3f} cx {cx:.1f} cy {cy:.1f}; "
        f"camera centre ({c[0]:+.3f}, {c[1]:+.3f}, {c[2]:+.3f}) m in the LiDAR frame; "
        f"{len(data)} points; wrote {a.out}"
    )


if __name__ == "__main__":
    main()
