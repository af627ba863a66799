#!/usr/bin/env python3
"""Measurement aid (not part of the product): KITTI-360 camera 00 as an infraloc camera file, its
official pose in the Velodyne frame, and seeded perturbed starts, for `infraloc refine` on
../shared/data/real/kitti360_0000 (docs/refine.md "Estimator").

The rectified perspective camera is the Mei model with xi = 0 and no distortion (P_rect_00). A
Velodyne point X projects as P_rect_00 · R_rect_00 · inv(T_cam0→velo) · X, so the camera's pose in
the Velodyne frame is R = R_rect_00 · R_velo→cam0, t = R_rect_00 · t_velo→cam0, with R_rect_00
(printed with six decimals) projected onto the nearest rotation by SVD first.

usage: kitti360_setup.py DATA_DIR OUT_DIR [--starts N] [--seed S] [--xyz 0.3] [--yaw 2]
writes OUT_DIR/cam.yaml, OUT_DIR/calib.json and OUT_DIR/start_K.json (K = 1..N): the start moved
by the search's own move (centre shifted by x, y, z uniform in ±xyz m in the Velodyne frame, yaw
uniform in ±yaw ° about its up axis through the camera centre), numpy's seeded generator.
"""
import argparse
import json
import os

import numpy as np


def read_kv(path):
    out = {}
    with open(path) as f:
        for line in f:
            if ":" in line:
                k, v = line.split(":", 1)
                out[k.strip()] = v.strip()
    return out


def nearest_rotation(m):
    u, _, vt = np.linalg.svd(m)
    r = u @ vt
    if np.linalg.det(r) < 0:
        u[:, -1] *= -1
        r = u @ vt
    return r


def pose_json(r, t):
    return {
        "rotation_cam_from_map": r.tolist(),
        "translation_cam_from_map": t.tolist(),
        "crs": "LOCAL",
    }


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("data")
    ap.add_argument("out")
    ap.add_argument("--starts", type=int, default=6)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--xyz", type=float, default=0.3)
    ap.add_argument("--yaw", type=float, default=2.0)
    a = ap.parse_args()
    os.makedirs(a.out, exist_ok=True)
    persp = read_kv(os.path.join(a.data, "calibration", "perspective.txt"))
    w, h = (int(float(v)) for v in persp["S_rect_00"].split())
    p = np.array([float(v) for v in persp["P_rect_00"].split()]).reshape(3, 4)
    r_rect = nearest_rotation(np.array([float(v) for v in persp["R_rect_00"].split()]).reshape(3, 3))
    cam_to_velo = np.loadtxt(os.path.join(a.data, "calibration", "calib_cam_to_velo.txt")).reshape(3, 4)
    r_cv, t_cv = cam_to_velo[:, :3], cam_to_velo[:, 3]
    r_vc = r_cv.T
    t_vc = -r_vc @ t_cv
    r = r_rect @ r_vc
    t = r_rect @ t_vc
    assert abs(p[0, 3]) < 1e-9 and abs(p[1, 3]) < 1e-9, "P_rect_00 has a baseline column"
    yaml = (
        "%YAML:1.0\n---\nmodel: mei\n"
        f"image_width: {w}\nimage_height: {h}\n"
        "camera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n"
        f"   data: [ {float(p[0,0])!r}, {float(p[0,1])!r}, {float(p[0,2])!r}, 0., {float(p[1,1])!r}, {float(p[1,2])!r}, 0., 0., 1. ]\n"
        "distortion_coefficients: !!opencv-matrix\n   rows: 1\n   cols: 4\n   dt: d\n"
        "   data: [ 0., 0., 0., 0. ]\n"
        "xi: !!opencv-matrix\n   rows: 1\n   cols: 1\n   dt: d\n   data: [ 0. ]\n"
    )
    with open(os.path.join(a.out, "cam.yaml"), "w") as f:
        f.write(yaml)
    with open(os.path.join(a.out, "calib.json"), "w") as f:
        json.dump(pose_json(r, t), f, indent=1)
    rng = np.random.default_rng(a.seed)
    c = -r.T @ t
    for k in range(1, a.starts + 1):
        d = rng.uniform(-a.xyz, a.xyz, 3)
        psi = np.radians(rng.uniform(-a.yaw, a.yaw))
        rz = np.array([[np.cos(psi), -np.sin(psi), 0], [np.sin(psi), np.cos(psi), 0], [0, 0, 1]])
        map_from_cam = rz @ r.T
        r2 = map_from_cam.T
        c2 = c + d
        with open(os.path.join(a.out, f"start_{k}.json"), "w") as f:
            json.dump(pose_json(r2, -r2 @ c2), f, indent=1)
        print(f"start_{k}: dx {d[0]:+.3f} dy {d[1]:+.3f} dz {d[2]:+.3f} m, yaw {np.degrees(psi):+.2f} deg")


if __name__ == "__main__":
    main()
