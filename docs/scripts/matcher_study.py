#!/usr/bin/env python3
"""Matcher study: do classical detectors/descriptors cross the satellite <-> fisheye modality gap?

What it measures
----------------
For each simulated scene (``infraloc simulate --preset small --difficulty hard --seed N``) it
matches two fisheye-derived views against a satellite crop with classical local features
(OpenCV SIFT, ORB with nfeatures=5000, AKAZE) and counts how many of the geometrically verified
matches are actually correct. It is an external baseline for infraloc's own dense yaw x height
sweep (src/localize/matching.rs); it uses OpenCV only and nothing of infraloc except the
simulator binary.

* Fisheye image: per-pixel median of the scene's frames (as the pipeline does).
* Intrinsics: the GIVEN ones (camera.yaml, slightly wrong on hard), never the true ones, to
  build the views.
* Satellite crop: 60 m x 60 m (600 x 600 px at 0.1 m/px) centred on the TRUE camera centre's
  ground point (this isolates the matching question from the GPS error), converted to gray.
* View "persp": cv2.omnidir perspective rectification (RECTIFY_PERSPECTIVE), identity rotation
  (the camera looks at nadir), 800 x 800 px, 120 deg field across the width.
* View "bev": bird's-eye view at a NOMINAL height of 8 m (true heights 3-15 m are unknown to a
  matcher): a 600 x 600 grid at 0.1 m/px on the plane z_cam = 8 m in the camera's own frame
  (camera x/y axes, yaw unknown), projected into the fisheye with the given intrinsics.
  Fisheye pixels outside the image are masked out.
* Variant "clahe" (optional, --clahe): the same with CLAHE applied to the view and the satellite.
* Positive control (optional, --control): the satellite crop replaced by the camera's own
  orthophoto on the same 0.1 m grid (median frame resampled with the TRUE pose and intrinsics),
  i.e. the same geometry and correctness test without the modality gap. It checks that the
  measurement can see correct matches when they exist.
* Matching: brute force (L2 for SIFT, Hamming for ORB/AKAZE), knn k=2, Lowe ratio 0.8, view ->
  satellite.
* Geometric verification (RANSAC, threshold measured in satellite-crop pixels):
  bev vs satellite: similarity (cv2.estimateAffinePartial2D; unknown yaw and scale), 5 px = 0.5 m;
  persp vs satellite: homography (cv2.findHomography), 5 px = 0.5 m.
  As a supplementary row, "bev-H": the bev matches verified with a homography instead (the ground
  under a tilted camera maps to the nominal BEV by a homography, not exactly a similarity).

How correctness is judged
-------------------------
Every view pixel remembers the fisheye pixel it was resampled from (the remap tables). A RANSAC
inlier (view keypoint, satellite keypoint) is CORRECT if the satellite keypoint - crop pixel ->
map (x, y) via the tile grid (pixel centre x = x0 + (col+0.5) res, y = y0 - (row+0.5) res),
z bilinear from height.tif - projected into the fisheye with the TRUE pose and the GIVEN
intrinsics lands within 10 px of the fisheye pixel the view keypoint came from. (The count with
the TRUE intrinsics is recorded too; the two differ by the ~3 px intrinsics error only.)
A scene is "usable" for a method if it has >= 12 correct inliers AND >= 50 % of its inliers are
correct (what a PnP + RANSAC downstream would need).

Before trusting the conventions the script checks, per scene, that the truth pose + TRUE
intrinsics reproduce the control points' fisheye pixels (< 0.5 px) and that height.tif agrees
with the control points' z; a scene failing the check is reported and skipped.

For comparison it reads a JSON written by examples/pipeline_accuracy.rs (--pipeline-json) and
reports how many of the same seeds infraloc's own initialization (PnP stage, with the real GPS
error) brings into the basin (horizontal <= 1 m and yaw <= 5 deg), and its median horizontal error.

Usage:
  python3 docs/scripts/matcher_study.py --infraloc PATH --seeds 1..20 --work DIR \
      [--pipeline-json FILE] [--clahe] [--control] [--json OUT]
"""

import argparse
import glob
import json
import os
import subprocess
import sys
import time

import cv2
import numpy as np

RES = 0.1            # satellite / BEV resolution, m/px
CROP = 600           # satellite crop and BEV side, px (60 m)
BEV_H = 8.0          # nominal BEV height, m
PERSP_SIZE = 800     # perspective view side, px
PERSP_FOV = 120.0    # perspective field across the width, deg
RATIO = 0.8          # Lowe ratio
RANSAC_PX = 5.0      # RANSAC threshold in satellite px (0.5 m)
CORRECT_PX = 10.0    # correctness tolerance in fisheye px
USABLE_MIN = 12
USABLE_PREC = 0.5


def parse_seeds(s):
    out = []
    for part in s.split(","):
        if ".." in part:
            a, b = part.split("..")
            out.extend(range(int(a), int(b) + 1))
        elif part:
            out.append(int(part))
    return out


def read_toml_grid(path):
    """Minimal reader for tile.toml: returns {layer: {key: value}} for [layers.X.grid] and
    [layers.X] file entries (no toml dependency needed)."""
    layers = {}
    section = None
    for line in open(path):
        line = line.strip()
        if line.startswith("["):
            section = line.strip("[]")
            continue
        if "=" not in line or section is None or not section.startswith("layers."):
            continue
        k, v = [p.strip() for p in line.split("=", 1)]
        parts = section.split(".")
        layer = parts[1]
        d = layers.setdefault(layer, {})
        if len(parts) == 3 and parts[2] == "grid":
            d[k] = float(v)
        elif len(parts) == 2 and k == "file":
            d["file"] = v.strip('"')
    return layers


def kdxi(i):
    K = np.array([[i["fx"], 0.0, i["cx"]], [0.0, i["fy"], i["cy"]], [0.0, 0.0, 1.0]])
    D = np.array([[i["k1"], i["k2"], i["p1"], i["p2"]]], dtype=np.float64)
    return K, D, float(i["xi"])


def given_intrinsics(camera_yaml):
    fs = cv2.FileStorage(camera_yaml, cv2.FILE_STORAGE_READ)
    K = fs.getNode("camera_matrix").mat().astype(np.float64)
    D = fs.getNode("distortion_coefficients").mat().astype(np.float64).reshape(1, 4)
    xi = float(fs.getNode("xi").mat().ravel()[0])
    w = int(fs.getNode("image_width").real())
    h = int(fs.getNode("image_height").real())
    fs.release()
    return K, D, xi, (w, h)


def project(Pmap, R, C, K, D, xi):
    """Map points (N,3) -> fisheye pixels (N,2); X_cam = R (X_map - C)."""
    if len(Pmap) == 0:
        return np.zeros((0, 2))
    rvec, _ = cv2.Rodrigues(R)
    obj = (np.asarray(Pmap, np.float64) - C).reshape(-1, 1, 3)
    ip, _ = cv2.omnidir.projectPoints(obj, rvec, np.zeros(3), K, xi, D)
    return ip.reshape(-1, 2)


def bilinear(img, xy):
    """Sample a float image at float pixel coordinates (N,2) (pixel centres at integers)."""
    if len(xy) == 0:
        return np.zeros(0)
    n = len(xy)
    w = 1024
    m = np.zeros(((n + w - 1) // w * w, 2), np.float32)
    m[:n] = np.asarray(xy, np.float32).reshape(-1, 2)
    m = m.reshape(-1, w, 2)  # remap needs dimensions < 32767
    out = cv2.remap(img.astype(np.float32), m[..., 0], m[..., 1], cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_REPLICATE)
    return out.reshape(-1)[:n].astype(np.float64)


class Grid:
    def __init__(self, g):
        self.x0, self.y0, self.res = g["x0"], g["y0"], g["res"]
        self.w, self.h = int(g["width"]), int(g["height"])

    def to_map(self, col, row):
        return self.x0 + (col + 0.5) * self.res, self.y0 - (row + 0.5) * self.res

    def to_pixel(self, x, y):
        return (x - self.x0) / self.res - 0.5, (self.y0 - y) / self.res - 0.5


def load_scene(d):
    truth = json.load(open(os.path.join(d, "truth.json")))
    tiles = glob.glob(os.path.join(d, "tiles", "*", "tile.toml"))
    assert len(tiles) == 1, tiles
    tdir = os.path.dirname(tiles[0])
    layers = read_toml_grid(tiles[0])
    sat = cv2.imread(os.path.join(tdir, layers["satellite"]["file"]), cv2.IMREAD_COLOR)
    height = cv2.imread(os.path.join(tdir, layers["height"]["file"]), cv2.IMREAD_UNCHANGED)
    height = height.astype(np.float32)
    if np.isnan(height).any():  # fill nodata with the median (only used for z of sat points)
        height = np.where(np.isnan(height), np.nanmedian(height), height).astype(np.float32)
    frames = sorted(glob.glob(os.path.join(d, "frames", "*.png")))
    stack = np.stack([cv2.imread(f, cv2.IMREAD_GRAYSCALE) for f in frames])
    median = np.median(stack, axis=0).astype(np.uint8)
    K, D, xi, size = given_intrinsics(os.path.join(d, "camera.yaml"))
    return dict(truth=truth, sat=sat, sat_grid=Grid(layers["satellite"]), height=height,
                h_grid=Grid(layers["height"]), frame=median, K=K, D=D, xi=xi, size=size)


def check_conventions(sc):
    t = sc["truth"]
    R = np.array(t["rotation_cam_from_map"])
    C = np.array(t["camera_center"])
    Kt, Dt, xit = kdxi(t["intrinsics"])
    P = np.array([c["map"] for c in t["control_points"]])
    px = np.array([c["pixel"] for c in t["control_points"]])
    err = np.linalg.norm(project(P, R, C, Kt, Dt, xit) - px, axis=1)
    hc, hr = sc["h_grid"].to_pixel(P[:, 0], P[:, 1])
    dz = bilinear(sc["height"], np.stack([hc, hr], 1)) - P[:, 2]
    return float(err.max()), float(np.median(np.abs(dz)))


def satellite_crop(sc, C):
    g = sc["sat_grid"]
    cc, cr = g.to_pixel(C[0], C[1])
    c0 = int(round(cc)) - CROP // 2
    r0 = int(round(cr)) - CROP // 2
    gray = cv2.cvtColor(sc["sat"], cv2.COLOR_BGR2GRAY)
    pad = CROP
    big = cv2.copyMakeBorder(gray, pad, pad, pad, pad, cv2.BORDER_CONSTANT, value=0)
    crop = big[r0 + pad:r0 + pad + CROP, c0 + pad:c0 + pad + CROP].copy()
    validb = cv2.copyMakeBorder(np.full_like(gray, 255), pad, pad, pad, pad,
                                cv2.BORDER_CONSTANT, value=0)
    mask = validb[r0 + pad:r0 + pad + CROP, c0 + pad:c0 + pad + CROP].copy()
    return crop, mask, (c0, r0)


def build_persp(sc):
    f = (PERSP_SIZE / 2) / np.tan(np.radians(PERSP_FOV / 2))
    Knew = np.array([[f, 0, PERSP_SIZE / 2 - 0.5], [0, f, PERSP_SIZE / 2 - 0.5], [0, 0, 1.0]])
    mx, my = cv2.omnidir.initUndistortRectifyMap(sc["K"], sc["D"], np.array([[sc["xi"]]]),
                                                 np.eye(3), Knew, (PERSP_SIZE, PERSP_SIZE),
                                                 cv2.CV_32FC1, cv2.omnidir.RECTIFY_PERSPECTIVE)
    return mx, my


def build_bev(sc):
    u = (np.arange(CROP) - (CROP - 1) / 2) * RES
    X, Y = np.meshgrid(u, u)
    pts = np.stack([X.ravel(), Y.ravel(), np.full(X.size, BEV_H)], 1).reshape(-1, 1, 3)
    ip, _ = cv2.omnidir.projectPoints(pts, np.zeros(3), np.zeros(3), sc["K"], sc["xi"], sc["D"])
    ip = ip.reshape(CROP, CROP, 2).astype(np.float32)
    return ip[..., 0].copy(), ip[..., 1].copy()


def view_from_maps(frame, mx, my, size):
    w, h = size
    img = cv2.remap(frame, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    valid = ((mx >= 1) & (mx <= w - 2) & (my >= 1) & (my <= h - 2)).astype(np.uint8) * 255
    valid = cv2.erode(valid, np.ones((15, 15), np.uint8))
    return img, valid


def detectors():
    return {
        "SIFT": (cv2.SIFT_create(), cv2.NORM_L2),
        "ORB": (cv2.ORB_create(nfeatures=5000), cv2.NORM_HAMMING),
        "AKAZE": (cv2.AKAZE_create(), cv2.NORM_HAMMING),
    }


def detect(det, img, mask):
    kp, des = det.detectAndCompute(img, mask)
    pts = np.array([k.pt for k in kp], np.float64).reshape(-1, 2)
    return pts, des


def ratio_matches(des_v, des_s, norm):
    if des_v is None or des_s is None or len(des_v) < 2 or len(des_s) < 2:
        return np.zeros((0, 2), int)
    bf = cv2.BFMatcher(norm)
    knn = bf.knnMatch(des_v, des_s, k=2)
    out = [(m[0].queryIdx, m[0].trainIdx) for m in knn
           if len(m) == 2 and m[0].distance < RATIO * m[1].distance]
    return np.array(out, int).reshape(-1, 2)


def verify(src, dst, model):
    """RANSAC; returns a boolean inlier mask."""
    n = len(src)
    if model == "similarity":
        if n < 3:
            return np.zeros(n, bool)
        M, inl = cv2.estimateAffinePartial2D(src.astype(np.float32), dst.astype(np.float32),
                                             method=cv2.RANSAC, ransacReprojThreshold=RANSAC_PX,
                                             maxIters=5000, confidence=0.999)
    else:
        if n < 5:
            return np.zeros(n, bool)
        M, inl = cv2.findHomography(src.astype(np.float32), dst.astype(np.float32), cv2.RANSAC,
                                    RANSAC_PX, maxIters=5000, confidence=0.999)
    if M is None or inl is None:
        return np.zeros(n, bool)
    return inl.ravel().astype(bool)


def run_scene(d, use_clahe, control=False):
    sc = load_scene(d)
    cp_err, dz = check_conventions(sc)
    t = sc["truth"]
    R = np.array(t["rotation_cam_from_map"])
    C = np.array(t["camera_center"])
    Kt, Dt, xit = kdxi(t["intrinsics"])
    res = dict(scene=d, seed=t.get("seed"), cp_max_px_true=cp_err, cp_median_dz_m=dz,
               camera_height_m=t["acquisition"]["camera_height_above_ground_m"], methods={})
    if cp_err > 0.5 or dz > 0.2:
        res["skipped"] = "convention check failed"
        return res
    crop, crop_mask, (c0, r0) = satellite_crop(sc, C)
    crop_mask = cv2.erode(crop_mask, np.ones((15, 15), np.uint8))
    sat_g, h_g = sc["sat_grid"], sc["h_grid"]

    views = {}
    mx, my = build_persp(sc)
    img, valid = view_from_maps(sc["frame"], mx, my, sc["size"])
    views["persp"] = (img, valid, mx, my)
    mx, my = build_bev(sc)
    img, valid = view_from_maps(sc["frame"], mx, my, sc["size"])
    views["bev"] = (img, valid, mx, my)

    variants = [("gray", None, crop, crop_mask)]
    if use_clahe:
        variants.append(("clahe", cv2.createCLAHE(clipLimit=3.0, tileGridSize=(8, 8)), crop,
                         crop_mask))
    if control:
        # Positive control: replace the satellite by the camera's own orthophoto on the same
        # crop grid (median frame resampled with the TRUE pose and TRUE intrinsics): same
        # geometry and correctness test, no modality gap.
        cols, rows = np.meshgrid(np.arange(CROP), np.arange(CROP))
        x, y = sat_g.to_map(cols.ravel() + c0, rows.ravel() + r0)
        hc, hr = h_g.to_pixel(x, y)
        z = bilinear(sc["height"], np.stack([hc, hr], 1))
        p = project(np.stack([x, y, z], 1), R, C, Kt, Dt, xit).reshape(CROP, CROP, 2)
        p = p.astype(np.float32)
        ortho, omask = view_from_maps(sc["frame"], p[..., 0].copy(), p[..., 1].copy(), sc["size"])
        variants.append(("control-ortho", None, ortho, cv2.bitwise_and(omask, crop_mask)))

    for vname, clahe, ref, ref_mask in variants:
        sat_img = clahe.apply(ref) if clahe is not None else ref
        for dname, (det, norm) in detectors().items():
            pts_s, des_s = detect(det, sat_img, ref_mask)
            # satellite keypoints -> map xyz -> fisheye pixels (truth pose, given / true intrinsics)
            sx, sy = sat_g.to_map(pts_s[:, 0] + c0, pts_s[:, 1] + r0)
            hc, hr = h_g.to_pixel(sx, sy)
            sz = bilinear(sc["height"], np.stack([hc, hr], 1))
            Pm = np.stack([sx, sy, sz], 1)
            pred_given = project(Pm, R, C, sc["K"], sc["D"], sc["xi"])
            pred_true = project(Pm, R, C, Kt, Dt, xit)
            for view, (img, valid, mx, my) in views.items():
                vimg = clahe.apply(img) if clahe is not None else img
                pts_v, des_v = detect(det, vimg, valid)
                m = ratio_matches(des_v, des_s, norm)
                src = pts_v[m[:, 0]] if len(m) else np.zeros((0, 2))
                dst = pts_s[m[:, 1]] if len(m) else np.zeros((0, 2))
                # fisheye pixel each view keypoint came from
                fish = np.stack([bilinear(mx, src), bilinear(my, src)], 1) if len(m) else src
                models = [("", "homography")] if view == "persp" else \
                    [("", "similarity"), ("-H", "homography")]
                for suffix, model in models:
                    inl = verify(src, dst, model)
                    ok_g = np.linalg.norm(fish - pred_given[m[:, 1]], axis=1) < CORRECT_PX \
                        if len(m) else np.zeros(0, bool)
                    ok_t = np.linalg.norm(fish - pred_true[m[:, 1]], axis=1) < CORRECT_PX \
                        if len(m) else np.zeros(0, bool)
                    n_in = int(inl.sum())
                    n_ok = int((inl & ok_g).sum())
                    key = f"{dname}/{view}{suffix}/{vname}"
                    res["methods"][key] = dict(
                        kp_view=len(pts_v), kp_sat=len(pts_s), matches=int(len(m)),
                        correct_matches=int(ok_g.sum()), inliers=n_in, correct=n_ok,
                        correct_true_intr=int((inl & ok_t).sum()),
                        precision=(n_ok / n_in) if n_in else 0.0,
                        usable=bool(n_ok >= USABLE_MIN and n_in > 0 and n_ok / n_in >= USABLE_PREC))
    return res


def pipeline_summary(path, seeds):
    d = json.load(open(path))
    rows = {s["seed"]: s for s in d["seeds"]}
    inb, hs, missing = 0, [], []
    for s in seeds:
        r = rows.get(s)
        p = r and r.get("errors", {}).get("pnp")
        if not p:
            missing.append(s)
            continue
        hs.append(p["horizontal_m"])
        if p["horizontal_m"] <= 1.0 and p["yaw_deg"] <= 5.0:
            inb += 1
    return dict(in_basin=inb, n=len(seeds), pnp_horizontal_median_m=float(np.median(hs)) if hs else None,
                missing=missing, command=d.get("command"))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--infraloc", required=True, help="infraloc binary (for `simulate`)")
    ap.add_argument("--seeds", default="1..20")
    ap.add_argument("--work", required=True, help="scene directory root (scenes reused if present)")
    ap.add_argument("--pipeline-json", default=None,
                    help="examples/pipeline_accuracy.rs JSON for the infraloc comparison")
    ap.add_argument("--clahe", action="store_true", help="also run the CLAHE variant")
    ap.add_argument("--control", action="store_true",
                    help="also run the positive control (camera orthophoto instead of satellite)")
    ap.add_argument("--json", default=None, help="write per-scene results here")
    a = ap.parse_args()
    seeds = parse_seeds(a.seeds)
    os.makedirs(a.work, exist_ok=True)
    cv2.setRNGSeed(0)
    results = []
    t0 = time.time()
    for s in seeds:
        d = os.path.join(a.work, f"s{s}")
        if not os.path.exists(os.path.join(d, "truth.json")):
            subprocess.run([a.infraloc, "simulate", "--preset", "small", "--seed", str(s),
                            "--difficulty", "hard", "--out", d], check=True,
                           stdout=subprocess.DEVNULL)
        r = run_scene(d, a.clahe, a.control)
        results.append(r)
        line = " ".join(f"{k.split('/')[0]}/{k.split('/')[1]}:{v['correct']}/{v['inliers']}"
                        for k, v in r["methods"].items() if k.endswith("/gray"))
        print(f"seed {s:3d} h={r['camera_height_m']:.1f}m cp={r['cp_max_px_true']:.2g}px "
              f"dz={r['cp_median_dz_m']:.3f}m {r.get('skipped', '')} {line}  [{time.time()-t0:.0f}s]",
              flush=True)
    if a.json:
        json.dump(results, open(a.json, "w"), indent=1)

    keys = []
    for r in results:
        for k in r["methods"]:
            if k not in keys:
                keys.append(k)
    n = len(results)
    print()
    print(f"RANSAC {RANSAC_PX:g} sat px; correct = within {CORRECT_PX:g} fisheye px; usable = "
          f">= {USABLE_MIN} correct and >= {USABLE_PREC:.0%} precision; {n} scenes")
    print("| method (detector/view/model/variant) | usable | median matches | median inliers "
          "| median correct inliers | median inlier precision | median correct among all matches |")
    print("|---|---|---|---|---|---|---|")
    for k in keys:
        rows = [r["methods"][k] for r in results if k in r["methods"]]
        us = sum(x["usable"] for x in rows)
        med = lambda f: float(np.median([f(x) for x in rows]))
        print(f"| {k} | {us}/{len(rows)} | {med(lambda x: x['matches']):.0f} | "
              f"{med(lambda x: x['inliers']):.0f} | {med(lambda x: x['correct']):.0f} | "
              f"{med(lambda x: x['precision']):.2f} | {med(lambda x: x['correct_matches']):.0f} |")
    if a.pipeline_json and os.path.exists(a.pipeline_json):
        p = pipeline_summary(a.pipeline_json, seeds)
        print()
        print(f"infraloc init (PnP stage, real GPS error; {a.pipeline_json}): "
              f"{p['in_basin']}/{p['n']} in basin (horizontal <= 1 m, yaw <= 5 deg), "
              f"PnP horizontal median {p['pnp_horizontal_median_m']:.3f} m"
              + (f", missing seeds {p['missing']}" if p["missing"] else ""))
    print(f"total {time.time()-t0:.0f}s")


if __name__ == "__main__":
    main()
