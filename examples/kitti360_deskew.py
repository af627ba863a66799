#!/usr/bin/env python3
"""Measurement aid (not part of the product): de-skew the sweeps of ../shared/data/real/kitti360_0000
with the drive's own poses, for the measurement in docs/refine.md "Open" (pooled real frames).

A KITTI-360 sweep is not motion-compensated: the Velodyne (HDL-64E, 10 Hz, spinning clockwise seen
from above) takes a point at azimuth a (atan2(y, x) in its frame, x forward, y left) at
t = -a / (2π · 10 Hz) from the forward crossing, when the camera is triggered. Each point is moved
to where it was at the forward crossing: X + t · (v + ω × X), with the sensor's velocity v and
angular rate ω (its frame) from the poses of the frame's neighbours in poses/poses.txt (world ←
IMU/GPS) and their times in poses/velodyne_timestamps.txt, through calib_cam_to_pose.txt and
calib_cam_to_velo.txt. Frame 100 has no pose: frames 97 and 99 stand in for its neighbours.

usage: kitti360_deskew.py DATA_DIR OUT_DIR [--spin -1|1]
writes OUT_DIR/velodyne/NNNNNNNNNN.bin (same format) and links OUT_DIR/image_00 to the images;
--spin 1 is the opposite spin, for checking the sign (it lowered the pooled MI).
"""
import argparse
import datetime
import os

import numpy as np

FRAMES = [100, 250, 360, 570, 644, 729, 947, 1134, 1280, 1338]


def rigid(path):
    """The 3×4 transform of a calibration file (its `image_00:` line when it has one) as 4×4."""
    with open(path) as f:
        text = f.read()
    for line in text.splitlines():
        if line.startswith("image_00:"):
            text = line.split(":", 1)[1]
            break
    m = np.array(text.split(), dtype=float).reshape(3, 4)
    return np.vstack([m, [0, 0, 0, 1]])


def log_rotation(r):
    c = np.clip((np.trace(r) - 1) / 2, -1, 1)
    angle = np.arccos(c)
    w = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]]) / 2
    return w if angle < 1e-9 else w * angle / np.sin(angle)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("data")
    ap.add_argument("out")
    ap.add_argument("--spin", type=float, default=-1.0)
    a = ap.parse_args()
    poses = {}
    with open(os.path.join(a.data, "poses/poses.txt")) as f:
        for line in f:
            v = line.split()
            poses[int(v[0])] = np.array(v[1:], dtype=float).reshape(3, 4)
    times = {}
    with open(os.path.join(a.data, "poses/velodyne_timestamps.txt")) as f:
        for line in f:
            k, day, clock = line.split()
            t = datetime.datetime.strptime(day + " " + clock[:15], "%Y-%m-%d %H:%M:%S.%f")
            times[int(k)] = t.replace(tzinfo=datetime.timezone.utc).timestamp()
    cal = os.path.join(a.data, "calibration")
    pose_from_velo = rigid(os.path.join(cal, "calib_cam_to_pose.txt")) @ np.linalg.inv(
        rigid(os.path.join(cal, "calib_cam_to_velo.txt"))
    )
    r_pv, t_pv = pose_from_velo[:3, :3], pose_from_velo[:3, 3]
    os.makedirs(os.path.join(a.out, "velodyne"), exist_ok=True)
    link = os.path.join(a.out, "image_00")
    if not os.path.exists(link):
        os.symlink(os.path.abspath(os.path.join(a.data, "image_00")), link)
    for frame in FRAMES:
        before, after, at = (97, 99, 99) if frame == 100 else (frame - 1, frame + 1, frame)
        dt = times[after] - times[before]
        r_at = poses[at][:, :3]
        v_pose = r_at.T @ (poses[after][:, 3] - poses[before][:, 3]) / dt
        w_pose = log_rotation(poses[before][:, :3].T @ poses[after][:, :3]) / dt
        v = r_pv.T @ (v_pose + np.cross(w_pose, t_pv))
        w = r_pv.T @ w_pose
        name = "%010d.bin" % frame
        pts = np.fromfile(os.path.join(a.data, "velodyne", name), dtype="<f4").reshape(-1, 4)
        x = pts[:, :3].astype(np.float64)
        t = a.spin * np.arctan2(x[:, 1], x[:, 0]) / (2 * np.pi * 10.0)
        out = pts.copy()
        out[:, :3] = x + t[:, None] * (v[None, :] + np.cross(w[None, :], x))
        out.astype("<f4").tofile(os.path.join(a.out, "velodyne", name))
        print(f"{frame}: |v| {np.linalg.norm(v):.2f} m/s, yaw rate {np.degrees(w[2]):+.1f} °/s")


if __name__ == "__main__":
    main()
