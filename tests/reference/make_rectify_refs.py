#!/usr/bin/env python3
"""Reference maps and images for tests/it/rectify_reference.rs, made with OpenCV.

For each case: cv2.omnidir.initUndistortRectifyMap(..., RECTIFY_PERSPECTIVE) (or
cv2.fisheye.initUndistortRectifyMap for the equidistant case) with CV_32FC1 maps, then cv2.remap
(INTER_LINEAR, BORDER_CONSTANT 0) of the gray version of the shared OpenCV sample image.

Writes tests/data/rectify/<case>/:
  camera.toml  the camera in infraloc's native TOML form (same numbers as K, D, xi below)
  camera.yaml  (Mei cases) the same camera written by cv2.FileStorage (OpenCV FileStorage YAML)
  case.json    the `infraloc rectify` arguments: size [W, H], k [fx, fy, cx, cy], rotation (9, row-major)
  map.f32      map_x then map_y, float32 little-endian, W*H each (the --map-out layout)
  out.png      the rectified gray image (8-bit PNG)

Gray conversion: cv2.cvtColor(BGR2GRAY) of cv2.imread's colour decode (BT.601 weights), which is
what `infraloc rectify` does with colour input.

Run from the repository root: python3 tests/reference/make_rectify_refs.py
"""
import json
import os

import cv2
import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
SAMPLE = os.path.join(ROOT, "..", "shared", "data", "omnidir", "sample.jpg")
OUT = os.path.join(ROOT, "tests", "data", "rectify")


def mei_case(name, fx, fy, cx, cy, skew, xi, d, rvec, p, size):
    return dict(name=name, model="mei", fx=fx, fy=fy, cx=cx, cy=cy, skew=skew, xi=xi, d=d,
                rvec=rvec, p=p, size=size)


CASES = [
    # Plain omnidir intrinsics, a tilted virtual view.
    mei_case("mei_a", 390.0, 390.0, 320.0, 240.0, 0.0, 1.05, [-0.2, 0.05, 1e-3, -5e-4],
             [0.15, -0.25, 0.1], [160.0, 160.0, 160.0, 120.0], (320, 240)),
    # Skewed K (K[0][1] != 0), anisotropic focal lengths, a wide and strongly rotated view.
    mei_case("mei_skew", 385.5, 392.25, 318.4, 243.7, 2.5, 0.98, [-0.18, 0.03, -8e-4, 1.2e-3],
             [-0.3, 0.2, 0.6], [45.0, 50.0, 100.0, 75.0], (200, 150)),
]

# cv::fisheye model (equidistant). All rays of this view are in front of the camera (theta < 90 deg),
# the region where OpenCV's atan(r) and infraloc's atan2 agree. alpha (K[0][1] = alpha * fx) is 0:
# cv::fisheye::initUndistortRectifyMap ignores K[0][1] (only fx, fy, cx, cy are read), unlike
# cv::fisheye::projectPoints; infraloc's map uses the full model, so with skew they would differ.
FISHEYE = dict(name="equidistant", fx=210.0, fy=211.0, cx=322.0, cy=238.0, alpha=0.0,
               d=[0.05, -0.01, 0.002, -0.0005], rvec=[0.1, 0.2, -0.3],
               p=[120.0, 120.0, 80.0, 60.0], size=(160, 120))


def pmat(p):
    return np.array([[p[0], 0.0, p[2]], [0.0, p[1], p[3]], [0.0, 0.0, 1.0]])


def write_case(c, cam_toml, mx, my, gray):
    d = os.path.join(OUT, c["name"])
    os.makedirs(d, exist_ok=True)
    r = cv2.Rodrigues(np.array(c["rvec"], dtype=np.float64))[0]
    with open(os.path.join(d, "camera.toml"), "w") as f:
        f.write(cam_toml)
    with open(os.path.join(d, "case.json"), "w") as f:
        json.dump({"size": list(c["size"]), "k": c["p"],
                   "rotation": [float(v) for v in r.ravel()]}, f, indent=1)
        f.write("\n")
    with open(os.path.join(d, "map.f32"), "wb") as f:
        f.write(mx.astype("<f4").tobytes())
        f.write(my.astype("<f4").tobytes())
    out = cv2.remap(gray, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    cv2.imwrite(os.path.join(d, "out.png"), out)
    h, w = gray.shape
    inside = (mx >= 0) & (my >= 0) & (mx <= w - 1) & (my <= h - 1)
    print(f"{c['name']}: {c['size']}, {inside.mean() * 100:.1f}% of pixels map inside the image")


def main():
    bgr = cv2.imread(SAMPLE, cv2.IMREAD_COLOR)
    assert bgr is not None, SAMPLE
    gray = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
    h, w = gray.shape
    for c in CASES:
        k = np.array([[c["fx"], c["skew"], c["cx"]], [0.0, c["fy"], c["cy"]], [0.0, 0.0, 1.0]])
        d = np.array([c["d"]], dtype=np.float64)
        xi = np.array([[c["xi"]]], dtype=np.float64)
        r = cv2.Rodrigues(np.array(c["rvec"], dtype=np.float64))[0]
        mx, my = cv2.omnidir.initUndistortRectifyMap(k, d, xi, r, pmat(c["p"]), c["size"],
                                                     cv2.CV_32FC1,
                                                     cv2.omnidir.RECTIFY_PERSPECTIVE)
        toml = (f'model = "mei"\nwidth = {w}\nheight = {h}\nfx = {c["fx"]!r}\nfy = {c["fy"]!r}\n'
                f'cx = {c["cx"]!r}\ncy = {c["cy"]!r}\nskew = {c["skew"]!r}\nxi = {c["xi"]!r}\n'
                f'k1 = {c["d"][0]!r}\nk2 = {c["d"][1]!r}\np1 = {c["d"][2]!r}\np2 = {c["d"][3]!r}\n')
        write_case(c, toml, mx, my, gray)
        fs = cv2.FileStorage(os.path.join(OUT, c["name"], "camera.yaml"), cv2.FILE_STORAGE_WRITE)
        fs.write("image_width", w)
        fs.write("image_height", h)
        fs.write("camera_matrix", k)
        fs.write("distortion_coefficients", d)
        fs.write("xi", xi)
        fs.release()

    c = FISHEYE
    k = np.array([[c["fx"], c["alpha"] * c["fx"], c["cx"]], [0.0, c["fy"], c["cy"]],
                  [0.0, 0.0, 1.0]])
    d = np.array(c["d"], dtype=np.float64).reshape(4, 1)
    r = cv2.Rodrigues(np.array(c["rvec"], dtype=np.float64))[0]
    p = pmat(c["p"])
    ww, hh = c["size"]
    u, v = np.meshgrid(np.arange(ww, dtype=np.float64), np.arange(hh, dtype=np.float64))
    rays = np.linalg.inv(p @ r) @ np.stack([u.ravel(), v.ravel(), np.ones(u.size)])
    assert (rays[2] > 0).all(), "fisheye case must keep every ray in front of the camera"
    mx, my = cv2.fisheye.initUndistortRectifyMap(k, d, r, p, c["size"], cv2.CV_32FC1)
    toml = (f'model = "equidistant"\nwidth = {w}\nheight = {h}\nfx = {c["fx"]!r}\n'
            f'fy = {c["fy"]!r}\ncx = {c["cx"]!r}\ncy = {c["cy"]!r}\nalpha = {c["alpha"]!r}\n'
            f'k1 = {c["d"][0]!r}\nk2 = {c["d"][1]!r}\nk3 = {c["d"][2]!r}\nk4 = {c["d"][3]!r}\n')
    write_case(c, toml, mx, my, gray)


if __name__ == "__main__":
    main()
