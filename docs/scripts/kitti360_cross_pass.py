#!/usr/bin/env python3
"""A KITTI-360 camera in a map made from another pass's scan, as `infraloc refine` inputs.

Issue 65 item 5. KITTI-360 drive 0000 comes back to places it passed before (the data's README,
"two places seen twice"): frames 947 and 1134 lie 22 m apart (facing each other: the car turned
between them), 1280 and 1338 lie 47 m apart (same heading). For an ordered pair (query Q, map M)
this writes into OUT:

- `camera.yaml`: the rectified `image_00` camera, by `infraloc kitti import` (and its
  `velo_pose.json`, the calibration in the Velodyne frame, used here as a check);
- `map.csv`: M's sweep (float32 x, y, z, reflectance 0–1) put into KITTI-360's world frame by
  `velo→world = pose_M · cam0_to_pose · inv(cam0_to_velo)`, as `x,y,z,reflectivity` with the
  reflectance scaled to 0–255 exactly as `refine --points FILE.bin` scales it (×255, rounded);
- `truth.json`: Q's rectified camera in the world frame (`"crs": "LOCAL"`),
  `cam0_to_world = pose_Q · cam0_to_pose · inv(R_rect_00)` (R_rect_00 orthonormalised by SVD);
- `start-1.json` … `start-3.json`: the three starts `refine --starts 3 --init truth.json` stands
  on (the truth, then ±0.2 m along world x with ±0.1 m height, +1° yaw: the tool's own spread,
  core/src/localize/refine/optima.rs `self_check_starts`), for runs one start at a time;
- `pair.json`: what was made and measured (distances, point counts, how many map points the
  query camera sees at the truth, the scans' nearest-neighbour distance in the world frame).

Points: the whole sweep is kept (walls, cars and trees too), as `kitti import --drive …
--pairs-out` and `refine --points FILE.bin` keep every point of a sweep (docs/kitti.md "Points"),
so the cross-pass runs differ from the single-frame runs only in the map. `--ground` keeps only
the points within 0.25 m of the lowest point of their 1 m × 1 m cell instead (a crude ground
filter, for comparison; not what the product's tile path will do).

The product's own path (the scans to `tile build` in a projected CRS, then `refine --tiles`)
waits for `tile build` from scans with poses (branch survey-tiles): `--via tiles` is the hook,
see `tile_inputs()`; today it stops with a message.

Usage:
  kitti360_cross_pass.py KITTI360_DIR OUT --query 947 --map 1134 [--bin target/release/infraloc]
      [--ground] [--via points|tiles]
Then:
  infraloc refine --camera OUT/camera.yaml --image KITTI360_DIR/image_00/0000000947.png \\
      --points OUT/map.csv --init OUT/truth.json --starts 3 --report OUT/report.json
Needs numpy and cv2 (cv2 only for the nearest-neighbour figure; without it that figure is
left out).
"""
import argparse
import json
import os
import subprocess
import sys

import numpy as np

# `refine --starts 3`'s starts as offsets from --init: x, y, z (m, map frame), yaw (deg).
# START_SPREAD = (0.2 m on a circle, 0.1 m height alternately, 1° yaw) at phases 0 and π.
STARTS = [(0.0, 0.0, 0.0, 0.0), (0.2, 0.0, 0.1, 1.0), (-0.2, 0.0, -0.1, 1.0)]


def read_kv(path):
    """`key: numbers…` lines → {key: np.array}. Lines whose values are not numbers are skipped."""
    out = {}
    for line in open(path):
        if ":" not in line:
            continue
        k, v = line.split(":", 1)
        try:
            out[k.strip()] = np.array([float(x) for x in v.split()])
        except ValueError:
            pass
    return out


def h(m34):
    """3×4 (12 numbers) → 4×4."""
    return np.vstack([np.asarray(m34, float).reshape(3, 4), [0.0, 0.0, 0.0, 1.0]])


def orthonormal(r):
    u, _, vt = np.linalg.svd(r)
    q = u @ vt
    if np.linalg.det(q) < 0:
        sys.exit("R_rect_00 is not near a rotation")
    return q


def poses(path):
    out = {}
    for line in open(path):
        v = line.split()
        if len(v) == 13:
            out[int(v[0])] = h([float(x) for x in v[1:]])
    return out


def rig(kdir):
    """cam0_to_pose, cam0_to_velo (4×4) and R_rect_00 (orthonormalised, 4×4) of the drive."""
    cal = os.path.join(kdir, "calibration")
    c2p = h(read_kv(os.path.join(cal, "calib_cam_to_pose.txt"))["image_00"])
    raw = open(os.path.join(cal, "calib_cam_to_velo.txt")).read().split()
    c2v = h([float(x) for x in raw])
    rect = np.eye(4)
    rect[:3, :3] = orthonormal(read_kv(os.path.join(cal, "perspective.txt"))["R_rect_00"].reshape(3, 3))
    return c2p, c2v, rect


def velodyne(kdir, frame):
    p = os.path.join(kdir, "velodyne", f"{frame:010d}.bin")
    a = np.fromfile(p, dtype="<f4")
    if a.size % 4:
        sys.exit(f"{p}: not a whole number of x, y, z, reflectance records")
    return a.reshape(-1, 4).astype(np.float64)


def pose_json(cam_from_map, note):
    """An infraloc.pose.v1 pose-like JSON (what `refine --init` reads) for a 4×4 cam←map."""
    return {
        "schema": "infraloc.pose.v1",
        "crs": "LOCAL",
        "rotation_cam_from_map": cam_from_map[:3, :3].tolist(),
        "translation_cam_from_map": cam_from_map[:3, 3].tolist(),
        "note": note,
    }


def perturbed(cam_from_map, dx, dy, dz, dyaw_deg):
    """The search's move (core/src/pose.rs `perturbed`): yaw about the map's up axis through the
    camera centre, then the centre moved by (dx, dy, dz) in the map frame."""
    r, t = cam_from_map[:3, :3], cam_from_map[:3, 3]
    c = -r.T @ t + np.array([dx, dy, dz])
    a = np.radians(dyaw_deg)
    rz = np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])
    r2 = (rz @ r.T).T
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = r2, -r2 @ c
    return out


def ground_only(xyz, cell=1.0, band=0.25):
    """Points within `band` m above the lowest point of their `cell` × `cell` m column."""
    ij = np.floor(xyz[:, :2] / cell).astype(np.int64)
    _, inv = np.unique(ij, axis=0, return_inverse=True)
    inv = inv.ravel()
    low = np.full(inv.max() + 1, np.inf)
    np.minimum.at(low, inv, xyz[:, 2])
    return xyz[:, 2] <= low[inv] + band


def in_view(cam_from_map, xyz, fx, fy, cx, cy, w, hgt):
    """Which map points project into the image, in front of the camera, and their depths."""
    pc = xyz @ cam_from_map[:3, :3].T + cam_from_map[:3, 3]
    z = np.where(pc[:, 2] > 0.5, pc[:, 2], np.nan)
    with np.errstate(invalid="ignore"):
        u = fx * pc[:, 0] / z + cx
        v = fy * pc[:, 1] / z + cy
        inside = (u >= 0) & (u < w) & (v >= 0) & (v < hgt)
    return inside, pc[:, 2]


def nn_median(a, b):
    """Median distance from each point of `a` to its nearest point of `b` (cv2's FLANN k-d tree)."""
    try:
        import cv2
    except ImportError:
        return None
    idx = cv2.flann_Index(b.astype(np.float32), dict(algorithm=1, trees=4))
    _, d2 = idx.knnSearch(a.astype(np.float32), 1, params=dict(checks=64))
    return float(np.median(np.sqrt(d2)))


def tile_inputs(out, scan_world, args):
    """Hook for the product's path: M's scan → `tile build` in a projected CRS → `refine --tiles`.

    Not implemented here: it waits for `tile build` from scans with poses (branch survey-tiles).
    What it needs: the scan (world frame here) in a projected CRS (KITTI-360's world frame is a
    local metric frame with z up near Karlsruhe; an offset into UTM 32N, EPSG:32632, applied
    alike to the points, truth.json and the starts, serves), `tile build` into OUT/tiles (id
    e.g. `kitti360-M`), and truth.json / start-*.json rewritten with that `crs`; real_views.py
    --cross-via tiles then runs `refine --tiles OUT/tiles` in place of `--points OUT/map.csv`.
    Today's `tile build CLOUD.pcd --crs EPSG:N` already rasterises a cloud given in a map CRS;
    note that a tile keeps only the ground its filter finds (--ground-*), at --res, so the tile
    path compares with `--ground` here more than with every point."""
    sys.exit(
        "--via tiles: not yet; needs `tile build` from scans with poses (branch survey-tiles). "
        "See tile_inputs() in docs/scripts/kitti360_cross_pass.py."
    )


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("kitti360", help="KITTI-360 sample dir (calibration/, image_00/, velodyne/, poses/)")
    ap.add_argument("out")
    ap.add_argument("--query", type=int, required=True, help="frame whose camera is localized")
    ap.add_argument("--map", type=int, required=True, help="frame whose scan is the map")
    ap.add_argument("--bin", default="target/release/infraloc")
    ap.add_argument("--ground", action="store_true", help="keep only a crude ground band of the scan")
    ap.add_argument("--via", choices=["points", "tiles"], default="points")
    a = ap.parse_args()
    k = a.kitti360
    os.makedirs(a.out, exist_ok=True)
    image = os.path.join(k, "image_00", f"{a.query:010d}.png")

    # The camera file (and the calibration in the Velodyne frame) by the product itself.
    cmd = [a.bin, "kitti", "import", "--calib", k, "--camera", "00", "--image", image,
           "--camera-out", os.path.join(a.out, "camera.yaml"),
           "--pose-out", os.path.join(a.out, "velo_pose.json")]
    print("+ " + " ".join(cmd), file=sys.stderr)
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)

    c2p, c2v, rect = rig(k)
    ps = poses(os.path.join(k, "poses", "poses.txt"))
    for f in (a.query, a.map):
        if f not in ps:
            sys.exit(f"frame {f} has no pose in poses/poses.txt")
    velo_to_world = ps[a.map] @ c2p @ np.linalg.inv(c2v)
    cam_to_world = ps[a.query] @ c2p @ np.linalg.inv(rect)
    truth = np.linalg.inv(cam_to_world)

    # Check the chain against `kitti import`'s own pose (rectified cam ← Velodyne) through frame
    # M: truth_M · velo→world_M must be it.
    vp = json.load(open(os.path.join(a.out, "velo_pose.json")))
    cam_from_velo = np.eye(4)
    cam_from_velo[:3, :3] = vp["rotation_cam_from_map"]
    cam_from_velo[:3, 3] = vp["translation_cam_from_map"]
    truth_m = np.linalg.inv(ps[a.map] @ c2p @ np.linalg.inv(rect))
    gap = np.abs(truth_m @ velo_to_world - cam_from_velo).max()
    if gap > 1e-5:
        sys.exit(f"the world chain disagrees with kitti import's pose by {gap:.2e}")

    scan = velodyne(k, a.map)
    xyz = scan[:, :3] @ velo_to_world[:3, :3].T + velo_to_world[:3, 3]
    refl = np.minimum(np.floor(scan[:, 3] * 255.0 + 0.5), 255.0).astype(int)
    if scan[:, 3].max() > 1.0:
        sys.exit("reflectance above 1: not a KITTI sweep")
    keep = ground_only(xyz) if a.ground else np.ones(len(xyz), bool)
    xyz, refl = xyz[keep], refl[keep]
    if a.via == "tiles":
        tile_inputs(a.out, xyz, a)
    with open(os.path.join(a.out, "map.csv"), "w") as f:
        f.write("x,y,z,reflectivity\n")
        for (x, y, z), r in zip(xyz, refl):
            f.write(f"{x:.4f},{y:.4f},{z:.4f},{r}\n")

    note = (f"KITTI-360 drive 0000 frame {a.query}'s rectified image_00 in the world frame "
            f"(cam0_to_world); map from frame {a.map}'s scan")
    json.dump(pose_json(truth, note), open(os.path.join(a.out, "truth.json"), "w"), indent=2)
    for n, (dx, dy, dz, dyaw) in enumerate(STARTS, 1):
        s = pose_json(perturbed(truth, dx, dy, dz, dyaw),
                      f"{note}; start {n}: truth moved ({dx:+.2f}, {dy:+.2f}, {dz:+.2f}) m, yaw {dyaw:+.1f}°")
        json.dump(s, open(os.path.join(a.out, f"start-{n}.json"), "w"), indent=2)

    # What the query camera has to work with.
    intr = vp.get("intrinsics", {})
    cam = read_kv(os.path.join(k, "calibration", "perspective.txt"))
    pr = cam["P_rect_00"].reshape(3, 4)
    w, hgt = (int(v) for v in cam["S_rect_00"])
    fx, fy, cx, cy = pr[0, 0], pr[1, 1], pr[0, 2], pr[1, 2]
    view_map, depth_map = in_view(truth, xyz, fx, fy, cx, cy, w, hgt)
    own = velodyne(k, a.query)
    own_to_world = ps[a.query] @ c2p @ np.linalg.inv(c2v)
    own_world = own[:, :3] @ own_to_world[:3, :3].T + own_to_world[:3, 3]
    view_own, depth_own = in_view(truth, own_world, fx, fy, cx, cy, w, hgt)
    near = view_map & (depth_map <= 40.0)
    cq, cm = cam_to_world[:3, 3], (ps[a.map] @ c2p @ np.linalg.inv(rect))[:3, 3]
    fq, fm = cam_to_world[:3, 2], (ps[a.map] @ c2p)[:3, 2]
    d = cm - cq
    heading = np.degrees(np.arctan2(fm[1], fm[0]) - np.arctan2(fq[1], fq[0]))
    heading = (heading + 180.0) % 360.0 - 180.0
    fwd = fq[:2] / np.linalg.norm(fq[:2])
    info = {
        "query": a.query,
        "map": a.map,
        "points_kept": "ground band" if a.ground else "all",
        "map_points": int(len(xyz)),
        "map_points_in_view": int(view_map.sum()),
        "map_points_in_view_within_20m": int((view_map & (depth_map <= 20.0)).sum()),
        "map_points_in_view_within_40m": int(near.sum()),
        "map_points_in_view_median_depth_m": float(np.median(depth_map[view_map])) if view_map.any() else None,
        "own_scan_points_in_view": int(view_own.sum()),
        "own_scan_points_in_view_within_20m": int((view_own & (depth_own <= 20.0)).sum()),
        "own_scan_points_in_view_median_depth_m": float(np.median(depth_own[view_own])) if view_own.any() else None,
        "camera_distance_m": float(np.linalg.norm(d)),
        "map_camera_ahead_m": float(d[:2] @ fwd),
        "map_camera_left_m": float(d[:2] @ np.array([-fwd[1], fwd[0]])),
        "map_camera_higher_m": float(d[2]),
        "heading_difference_deg": float(heading),
        # Map points the camera sees within 40 m → the query's own sweep: how well the passes agree
        # where the camera looks (ring sparsity included).
        "scan_nn_median_m": nn_median(xyz[near], own_world) if near.any() else None,
        "check_chain_vs_kitti_import": float(gap),
        "intrinsics_model": intr.get("model"),
    }
    json.dump(info, open(os.path.join(a.out, "pair.json"), "w"), indent=2)
    print(
        f"query {a.query} in map {a.map}: map camera {info['camera_distance_m']:.1f} m away "
        f"({info['map_camera_ahead_m']:+.1f} m ahead, {info['map_camera_left_m']:+.1f} m left, "
        f"heading {heading:+.0f}°); {len(xyz)} map points ({info['points_kept']}), "
        f"{info['map_points_in_view']} in view, {info['map_points_in_view_within_20m']} within 20 m "
        f"(own scan: {info['own_scan_points_in_view']}, {info['own_scan_points_in_view_within_20m']}); "
        "map→own-scan NN median "
        f"{'n/a' if info['scan_nn_median_m'] is None else round(info['scan_nn_median_m'], 3)} m; "
        f"wrote {a.out}"
    )


if __name__ == "__main__":
    main()
