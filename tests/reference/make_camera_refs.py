#!/usr/bin/env python3
"""Reference data for the camera models (tests/it/camera_reference.rs).

Run from the repository root (needs numpy and opencv-contrib-python-headless<5, and ../shared beside
the clone for the omnidir calibration data):

    python3 tests/reference/make_camera_refs.py

It writes, under tests/data/camera/:

* intrinsics fixtures written by OpenCV itself (cv2.FileStorage, YAML and XML), among them the
  result of a real cv2.omnidir.calibrate run on opencv_contrib's omni_calib_data.xml, a
  KITTI-360-style MEI file (the nested layout CamOdoCal/KITTI-360 write with cv::FileStorage) and
  a Kalibr camchain;
* for each reference set <name>: <name>.pose.json (rotation_cam_from_map + translation_cam_from_map
  of a non-trivial rvec/tvec), <name>.points_cam.csv / <name>.points_map.csv (x,y,z in the camera /
  map frame) and <name>.uv_cam.csv / <name>.uv_map.csv (the expected u,v and which reference
  produced them).

References:
* Mei sets: cv2.omnidir.projectPoints (identity rvec/tvec for the camera frame, the pose's
  rvec/tvec for the map frame). Rays the model cannot map one-to-one (behind the mirror: sphere z <=
  -1/xi for xi > 1, z <= -xi otherwise; or past the radial distortion's fold) have empty u,v -
  OpenCV itself returns a number for them, but it belongs to a different ray.
* Equidistant sets: cv2.fisheye.projectPoints for theta < 90 deg. OpenCV's fisheye uses
  theta = atan(r) with r = |(x/z, y/z)|, which is wrong for theta >= 90 deg (z <= 0: the point is
  mirrored through the centre). Rays with theta >= 90 deg are compared against an independent numpy
  evaluation of the equidistant formula with theta = arctan2(rho, z). Where both apply (theta < 90
  deg) the script asserts the numpy formula matches OpenCV to 1e-9 px.
"""

import json
import math
import os
import sys

import cv2
import numpy as np

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", ".."))
OUT = os.path.join(ROOT, "tests", "data", "camera")
CALIB = os.path.join(ROOT, "..", "shared", "data", "omnidir", "omni_calib_data.xml")

# Test geometry: polar angles (deg) in the required 0..95 deg band, azimuths (deg), ranges (m).
THETAS = [0.0, 0.5, 5, 15, 30, 45, 60, 75, 85, 89, 89.9, 90, 90.1, 91, 93, 95]
AZIMUTHS = [0, 37, 90, 127, 180, 217, 270, 307]
RANGES = [0.3, 4.0, 55.0]
# Extra polar angles beyond 95 deg: projectable for some models, behind the mirror for others.
EXTRA_THETAS = [110, 130, 150, 170, 180]
EXTRA_AZIMUTHS = [15, 200, 290]
# The map-frame pose (OpenCV rvec/tvec of cam_from_map).
RVEC = np.array([0.3, -2.9, 0.4])
TVEC = np.array([12.5, -3.25, 40.0])


def fmt(v):
    return repr(float(v))


def write_csv(path, header, rows):
    with open(path, "w") as f:
        f.write(header + "\n")
        for r in rows:
            f.write(",".join(r) + "\n")


def unit(theta_deg, az_deg):
    if theta_deg == 180:
        return np.array([0.0, 0.0, -1.0])  # exactly, not sin(pi) ~ 1e-16 off the axis
    t, a = math.radians(theta_deg), math.radians(az_deg)
    return np.array([math.sin(t) * math.cos(a), math.sin(t) * math.sin(a), math.cos(t)])


def camera_points():
    """Camera-frame points: (x, y, z) rows (write_set appends the degenerate zero vector)."""
    pts = []
    for rng in RANGES:
        for th in THETAS:
            for az in AZIMUTHS if th > 0 else [0]:
                pts.append(rng * unit(th, az))
    for th in EXTRA_THETAS:
        for az in EXTRA_AZIMUTHS if th < 180 else [0]:
            pts.append(7.0 * unit(th, az))
    return np.array(pts)


# ------------------------------------------------------------------------------------------------
# Fixtures written by OpenCV
# ------------------------------------------------------------------------------------------------


def calibrate(flags):
    fs = cv2.FileStorage(CALIB, cv2.FILE_STORAGE_READ)
    op, ip = fs.getNode("objectPoints"), fs.getNode("imagePoints")
    obj = [op.at(i).mat().astype(np.float64) for i in range(op.size())]
    img = [ip.at(i).mat().astype(np.float64) for i in range(ip.size())]
    size = fs.getNode("imageSize")
    w, h = int(size.at(0).real()), int(size.at(1).real())
    crit = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-8)
    rms, K, xi, D, _, _, _ = cv2.omnidir.calibrate(obj, img, (w, h), None, None, None, flags, crit)
    print(f"omnidir.calibrate flags={flags}: rms={rms:.4f} px xi={xi.ravel()[0]:.4f} skew={K[0, 1]:.4f}")
    assert 0.7 < rms < 0.9 and 1.0 < xi.ravel()[0] < 1.1, "calibration result not the documented one"
    return dict(w=w, h=h, K=K, xi=float(xi.ravel()[0]), D=D.reshape(1, 4), rms=rms)


def write_opencv(path, cam, model=None, fov=None, comment=None):
    """cv::FileStorage layout of cv::omnidir / cv::fisheye tooling + our image size keys."""
    fs = cv2.FileStorage(path, cv2.FILE_STORAGE_WRITE)
    if comment:
        fs.writeComment(comment)
    if model:
        fs.write("model", model)
    fs.write("image_width", cam["w"])
    fs.write("image_height", cam["h"])
    fs.write("camera_matrix", cam["K"])
    fs.write("distortion_coefficients", cam["D"])
    if "xi" in cam:
        fs.write("xi", np.array([[cam["xi"]]]))
    if "rms" in cam:
        fs.write("rms", cam["rms"])
    if fov:
        fs.write("fov_deg", float(fov))
    fs.release()


def write_kitti360(path, cam):
    """The layout of KITTI-360's calibration/image_02.yaml (CamOdoCal MEI, written by FileStorage)."""
    fs = cv2.FileStorage(path, cv2.FILE_STORAGE_WRITE)
    fs.write("model_type", "MEI")
    fs.write("camera_name", "image_02")
    fs.write("image_width", cam["w"])
    fs.write("image_height", cam["h"])
    fs.startWriteStruct("mirror_parameters", cv2.FileNode_MAP)
    fs.write("xi", cam["xi"])
    fs.endWriteStruct()
    fs.startWriteStruct("distortion_parameters", cv2.FileNode_MAP)
    for k, v in zip(["k1", "k2", "p1", "p2"], cam["D"].ravel()):
        fs.write(k, float(v))
    fs.endWriteStruct()
    fs.startWriteStruct("projection_parameters", cv2.FileNode_MAP)
    K = cam["K"]
    for k, v in zip(["gamma1", "gamma2", "u0", "v0"], [K[0, 0], K[1, 1], K[0, 2], K[1, 2]]):
        fs.write(k, float(v))
    fs.endWriteStruct()
    fs.release()


def write_kalibr(path, cam0, cam1):
    """A Kalibr camchain (Kalibr writes it with PyYAML; this is that layout)."""

    def lst(v):
        return "[" + ", ".join(fmt(x) for x in v) + "]"

    K0, K1 = cam0["K"], cam1["K"]
    text = f"""cam0:
  cam_overlaps: [1]
  camera_model: omni
  distortion_coeffs: {lst(cam0["D"].ravel())}
  distortion_model: radtan
  intrinsics: {lst([cam0["xi"], K0[0, 0], K0[1, 1], K0[0, 2], K0[1, 2]])}
  resolution: [{cam0["w"]}, {cam0["h"]}]
  rostopic: /cam0/image_raw
cam1:
  T_cn_cnm1:
  - [0.9999, -0.0141, 0.0, 0.12]
  - [0.0141, 0.9999, 0.0, 0.0]
  - [0.0, 0.0, 1.0, 0.0]
  - [0.0, 0.0, 0.0, 1.0]
  cam_overlaps: [0]
  camera_model: pinhole
  distortion_coeffs: {lst(cam1["D"].ravel())}
  distortion_model: equidistant
  intrinsics: {lst([K1[0, 0], K1[1, 1], K1[0, 2], K1[1, 2]])}
  resolution: [{cam1["w"]}, {cam1["h"]}]
  rostopic: /cam1/image_raw
"""
    with open(path, "w") as f:
        f.write(text)


def kmat(fx, fy, cx, cy, skew=0.0):
    return np.array([[fx, skew, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


# ------------------------------------------------------------------------------------------------
# Reference projections
# ------------------------------------------------------------------------------------------------


def mei_valid(cam, xc):
    """Our documented validity rule (docs/camera.md), evaluated independently."""
    n = np.linalg.norm(xc)
    if n == 0:
        return False
    zs = xc[2] / n
    xi = cam["xi"]
    if zs <= (-1.0 / xi if xi > 1 else -xi):
        return False
    k1, k2 = cam["D"].ravel()[:2]
    # Fold of r(1 + k1 r^2 + k2 r^4): 1 + 3 k1 s + 5 k2 s^2 = 0, s = r^2.
    roots = [r.real for r in np.roots([5 * k2, 3 * k1, 1.0]) if abs(r.imag) < 1e-300 and r.real > 0]
    r2 = (xc[0] ** 2 + xc[1] ** 2) / (n * (zs + xi)) ** 2
    return not roots or r2 < min(roots)


def mei_refs(cam, pts_world, rvec, tvec):
    R, _ = cv2.Rodrigues(rvec)
    uv, _ = cv2.omnidir.projectPoints(
        pts_world.reshape(-1, 1, 3), rvec.reshape(3, 1), tvec.reshape(3, 1),
        cam["K"], cam["xi"], cam["D"])
    uv = uv.reshape(-1, 2)
    rows = []
    for p, q in zip(pts_world, uv):
        xc = R @ p + tvec
        if mei_valid(cam, xc):
            rows.append([fmt(q[0]), fmt(q[1]), "opencv"])
        else:
            rows.append(["", "", "rule"])
    return rows


def equidistant_numpy(cam, xc):
    """The equidistant formula with theta = arctan2(rho, z), independent of OpenCV."""
    k = cam["D"].ravel()
    K = cam["K"]
    alpha = K[0, 1] / K[0, 0]
    rho = math.hypot(xc[0], xc[1])
    th = math.atan2(rho, xc[2])
    th_d = th * (1 + k[0] * th**2 + k[1] * th**4 + k[2] * th**6 + k[3] * th**8)
    x, y = (xc[0] * th_d / rho, xc[1] * th_d / rho) if rho > 0 else (0.0, 0.0)
    return K[0, 0] * (x + alpha * y) + K[0, 2], K[1, 1] * y + K[1, 2]


def equidistant_monotonic(cam, th):
    """theta_d(theta) still increasing at th (checked on a fine grid up to th)."""
    k = cam["D"].ravel()
    t = np.linspace(0, th, 20001)
    d = 1 + 3 * k[0] * t**2 + 5 * k[1] * t**4 + 7 * k[2] * t**6 + 9 * k[3] * t**8
    return bool(np.all(d > 0))


def equidistant_refs(cam, pts_world, rvec, tvec):
    R, _ = cv2.Rodrigues(rvec)
    K = cam["K"]
    alpha = K[0, 1] / K[0, 0]
    uv, _ = cv2.fisheye.projectPoints(
        pts_world.reshape(-1, 1, 3), rvec.reshape(3, 1), tvec.reshape(3, 1), K, cam["D"].ravel(),
        alpha=alpha)
    uv = uv.reshape(-1, 2)
    rows = []
    for p, q in zip(pts_world, uv):
        xc = R @ p + tvec
        n = np.linalg.norm(xc)
        th = math.atan2(math.hypot(xc[0], xc[1]), xc[2]) if n > 0 else math.nan
        if not (n > 0) or th >= math.pi or not equidistant_monotonic(cam, th):
            rows.append(["", "", "rule"])
        elif th < math.pi / 2:
            u, v = equidistant_numpy(cam, xc)
            assert abs(u - q[0]) < 1e-9 and abs(v - q[1]) < 1e-9, (th, u, v, q)
            rows.append([fmt(q[0]), fmt(q[1]), "opencv"])
        else:
            u, v = equidistant_numpy(cam, xc)
            rows.append([fmt(u), fmt(v), "numpy"])
    return rows


def write_set(name, cam, kind):
    pts_cam = camera_points()
    R, _ = cv2.Rodrigues(RVEC)
    refs = mei_refs if kind == "mei" else equidistant_refs
    zero = np.zeros(3)
    # Rays beyond 95 deg that the model maps to pixels far off any sensor (xi < 1 near z = -xi: the
    # image radius grows without bound) are dropped: there the result is ill-conditioned for any
    # implementation (a 1e-16 change of the ray moves the pixel by more than the tolerance).
    rows = refs(cam, pts_cam, zero, zero)
    far = 2 * max(cam["w"], cam["h"])
    c0 = np.array([cam["K"][0, 2], cam["K"][1, 2]])
    keep = np.array([not r[0] or np.hypot(float(r[0]) - c0[0], float(r[1]) - c0[1]) < far
                     for r in rows])
    pts_cam = pts_cam[keep]
    # Map-frame points: X_w = R^T (X_c - t). The backward axis ray (theta = 180 deg) is left out of
    # the map set because R X_w + t recomputes it only to rounding, i.e. with an arbitrary
    # azimuth: ill-conditioned for any implementation.
    on_back_axis = (pts_cam[:, 0] == 0) & (pts_cam[:, 1] == 0) & (pts_cam[:, 2] < 0)
    pts_map = np.array([R.T @ (p - TVEC) for p in pts_cam[~on_back_axis]])
    sets = [("cam", np.vstack([pts_cam, zero]), zero, zero), ("map", pts_map, RVEC, TVEC)]
    for frame, pts, rvec, tvec in sets:
        rows = refs(cam, pts, rvec, tvec)
        if frame == "cam":
            rows[-1] = ["", "", "rule"]  # the appended zero vector: degenerate
        write_csv(os.path.join(OUT, f"{name}.points_{frame}.csv"), "x,y,z",
                  [[fmt(c) for c in p] for p in pts])
        write_csv(os.path.join(OUT, f"{name}.uv_{frame}.csv"), "u,v,reference", rows)
        counts = {k: sum(r[2] == k for r in rows) for k in ("opencv", "numpy", "rule")}
        print(f"{name} {frame}: {len(rows)} points {counts}")
    c = -R.T @ TVEC
    pose = {
        "schema": "infraloc.pose.v1",
        "status": "ok",
        "crs": "LOCAL",
        "tile_id": "reference",
        "camera_center": [float(v) for v in c],
        "rotation_cam_from_map": [[float(v) for v in row] for row in R],
        "translation_cam_from_map": [float(v) for v in TVEC],
        "rvec_cam_from_map": [float(v) for v in RVEC],
    }
    with open(os.path.join(OUT, f"{name}.pose.json"), "w") as f:
        json.dump(pose, f, indent=2)
        f.write("\n")


def main():
    os.makedirs(OUT, exist_ok=True)
    np.set_printoptions(precision=17)

    # (a) KITTI-360 image_02 (parameters as given in the issue), in KITTI-360's MEI layout.
    kitti = dict(w=1400, h=1400, K=kmat(1336.32, 1335.79, 716.94, 705.76), xi=2.2134,
                 D=np.array([[0.0168, 1.6549, 4.22e-4, 4.25e-4]]))
    write_kitti360(os.path.join(OUT, "kitti360_image_02.yaml"), kitti)
    # (b) a synthetic xi < 1 lens with a large skew, OpenCV YAML.
    skew = dict(w=1280, h=960, K=kmat(700.0, 702.0, 641.3, 479.2, skew=14.5), xi=0.9,
                D=np.array([[-0.2, 0.05, 1e-4, -2e-4]]))
    write_opencv(os.path.join(OUT, "synthetic_skew.yaml"), skew, model="mei")
    # (c) a real calibration: cv2.omnidir.calibrate on omni_calib_data.xml (skew fixed at 0).
    calib = calibrate(cv2.omnidir.CALIB_FIX_SKEW)
    write_opencv(os.path.join(OUT, "omni_calib.yaml"), calib,
                 comment="cv2.omnidir.calibrate(omni_calib_data.xml, flags=CALIB_FIX_SKEW)")
    # (b') the same data with the skew free (a real, small skew), as OpenCV XML.
    calib_skew = calibrate(0)
    write_opencv(os.path.join(OUT, "omni_calib_skew.xml"), calib_skew,
                 comment="cv2.omnidir.calibrate(omni_calib_data.xml, flags=0)")
    # Equidistant: a 185 deg lens with alpha != 0 (OpenCV YAML) and a Kalibr pinhole-equidistant.
    fish = dict(w=2448, h=2048, K=kmat(780.0, 781.5, 1223.7, 1025.1, skew=780.0 * 0.0021),
                D=np.array([[0.011, -0.0023, 0.00047, -0.00009]]))
    write_opencv(os.path.join(OUT, "fisheye185.yaml"), fish, model="equidistant", fov=185)
    kalibr_fish = dict(w=752, h=480, K=kmat(190.97, 190.97, 254.93, 256.89),
                       D=np.array([[0.0035, 0.0007,
                                    -0.0021, 0.0002]]))
    write_kalibr(os.path.join(OUT, "kalibr_camchain.yaml"), skew, kalibr_fish)

    write_set("kitti360_image_02", kitti, "mei")
    write_set("synthetic_skew", skew, "mei")
    write_set("omni_calib", calib, "mei")
    write_set("omni_calib_skew", calib_skew, "mei")
    write_set("fisheye185", fish, "equidistant")
    write_set("kalibr_cam1", kalibr_fish, "equidistant")


if __name__ == "__main__":
    sys.exit(main())
