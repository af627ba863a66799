#!/usr/bin/env python3
"""Independent reference for `infraloc kitti import` on KITTI-360 (tests/it/kitti_layouts.rs).

Usage: kitti360_reference.py CALIBRATION_DIR CAMERA POINTS.json

Reads KITTI-360's calibration files with numpy alone (not through infraloc), composes camera
CAMERA's pose in the Velodyne frame, and projects POINTS.json (a list of [x, y, z] in the
Velodyne frame). Prints JSON:
- "cam_from_velo": the 4x4 Velodyne -> camera transform (rectified for cameras 0 and 1),
- cameras 0, 1: "pinhole": P_rect_0N[:3, :3] . X_rect / z (the devkit's CameraPerspective),
- cameras 2, 3: "omnidir": cv2.omnidir.projectPoints with K = [[gamma1, 0, u0], [0, gamma2, v0],
  [0, 0, 1]], D = [k1, k2, p1, p2] and xi; "devkit": KITTI-360's CameraFisheye.cam2image
  formula, written out here (it applies k1, k2 and no tangential term).
Rotations are orthonormalised by SVD (the official R_rect_00 is 1.7e-6 from a rotation).
"""
import json
import os
import sys

import numpy as np


def key_numbers(path):
    out = {}
    with open(path) as f:
        for line in f:
            if ":" not in line:
                continue
            k, v = line.split(":", 1)
            try:
                out[k.strip()] = np.array([float(x) for x in v.split()])
            except ValueError:
                pass  # calib_time and other text values
    return out


def nearest_rotation(m):
    u, _, vt = np.linalg.svd(m)
    d = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))])
    return u @ d @ vt


def rigid(v12):
    t = np.eye(4)
    m = v12.reshape(3, 4)
    t[:3, :3] = nearest_rotation(m[:, :3])
    t[:3, 3] = m[:, 3]
    return t


def read_mei(path):
    # OpenCV-style YAML with nested sections; parsed by hand to stay free of a YAML package.
    vals = {}
    with open(path) as f:
        for line in f:
            s = line.strip()
            if ":" in s and not s.startswith("%"):
                k, v = s.split(":", 1)
                v = v.strip()
                if v:
                    try:
                        vals[k.strip()] = float(v)
                    except ValueError:
                        pass
    return vals


def main():
    calib, n, points_path = sys.argv[1], int(sys.argv[2]), sys.argv[3]
    pts = np.array(json.load(open(points_path)), dtype=np.float64).reshape(-1, 3)
    velo_from_cam0 = rigid(np.loadtxt(os.path.join(calib, "calib_cam_to_velo.txt")))
    if n == 0:
        velo_from_cam = velo_from_cam0
    else:
        c2p = key_numbers(os.path.join(calib, "calib_cam_to_pose.txt"))
        pose_from_cam0 = rigid(c2p["image_00"])
        pose_from_cam = rigid(c2p["image_%02d" % n])
        velo_from_cam = velo_from_cam0 @ np.linalg.inv(pose_from_cam0) @ pose_from_cam
    cam_from_velo = np.linalg.inv(velo_from_cam)
    out = {}
    xh = np.hstack([pts, np.ones((len(pts), 1))])
    if n in (0, 1):
        p = key_numbers(os.path.join(calib, "perspective.txt"))
        r_rect = np.eye(4)
        r_rect[:3, :3] = nearest_rotation(p["R_rect_%02d" % n].reshape(3, 3))
        cam_from_velo = r_rect @ cam_from_velo
        k = p["P_rect_%02d" % n].reshape(3, 4)[:, :3]
        xc = (cam_from_velo @ xh.T)[:3]
        uvw = k @ xc
        out["pinhole"] = [
            [float(uvw[0, i] / uvw[2, i]), float(uvw[1, i] / uvw[2, i])] if xc[2, i] > 0.1 else None
            for i in range(len(pts))
        ]
    else:
        import cv2

        m = read_mei(os.path.join(calib, "image_%02d.yaml" % n))
        xi, k1, k2, p1, p2 = m["xi"], m["k1"], m["k2"], m["p1"], m["p2"]
        g1, g2, u0, v0 = m["gamma1"], m["gamma2"], m["u0"], m["v0"]
        xc = (cam_from_velo @ xh.T)[:3].T
        kmat = np.array([[g1, 0.0, u0], [0.0, g2, v0], [0.0, 0.0, 1.0]])
        rvec, _ = cv2.Rodrigues(cam_from_velo[:3, :3])
        # omnidir.projectPoints reads rvec and tvec as 1x3 rows (a 3x1 tvec is misread).
        rvec, tvec = rvec.reshape(1, 3), cam_from_velo[:3, 3].reshape(1, 3)
        uv, _ = cv2.omnidir.projectPoints(
            pts.reshape(1, -1, 3), rvec, tvec, kmat, xi, np.array([[k1, k2, p1, p2]])
        )
        out["omnidir"] = uv.reshape(-1, 2).tolist()
        # KITTI-360 devkit, CameraFisheye.cam2image: unit sphere, shift by xi, k1/k2 only.
        norm = np.linalg.norm(xc, axis=1)
        x, y, z = xc[:, 0] / norm, xc[:, 1] / norm, xc[:, 2] / norm
        x, y = x / (z + xi), y / (z + xi)
        r2 = x * x + y * y
        rad = 1 + k1 * r2 + k2 * r2 * r2
        out["devkit"] = np.stack([g1 * x * rad + u0, g2 * y * rad + v0], axis=1).tolist()
    out["cam_from_velo"] = cam_from_velo.tolist()
    print(json.dumps(out))


if __name__ == "__main__":
    main()
