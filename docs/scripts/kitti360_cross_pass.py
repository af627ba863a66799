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
  query camera sees at the truth, the scans' nearest-neighbour distance in the world frame; with
  `--via tiles` the tile's id, CRS, offset, resolution and its `tile scans` command).

Points: the whole sweep is kept (walls, cars and trees too), as `kitti import --drive …
--pairs-out` and `refine --points FILE.bin` keep every point of a sweep (docs/kitti.md "Points"),
so the cross-pass runs differ from the single-frame runs only in the map. `--ground` keeps only
the points within 0.25 m of the lowest point of their 1 m × 1 m cell instead (a crude ground
filter, for comparison; not the tile path's filter).

`--via tiles`: the product's own path. In place of `map.csv`, M's sweep goes to `infraloc tile
scans` (docs/map.md "From a drive's scans to a tile"): posed by `poses/poses.txt` with
`--calib` (the same chain as above, the product's own reading of it), placed in `--crs`
(EPSG:32632, UTM 32N) by `--offset` (458265.478, 5425872.189, 0: the devkit's world origin in
UTM 32N, so map = world + offset), ground-filtered and rasterised at `--tile-res` (0.25 m) into
`OUT/tiles/kitti360-M`, a LiDAR-only tile. Its box is the sweep's extent and both cameras,
widened by 30 m, so `refine --tiles` finds a tile holding the query camera's whole --radius disc.
`truth.json` and `start-*.json` are then in the tile's frame: `"crs": "EPSG:32632"`, the camera
centre moved by the offset (the rotation orthonormalised first, as `refine` would, so the centre
is exact at UTM magnitudes). The tile keeps only the ground, at its resolution: no walls, cars
or trees, unlike `map.csv`.

Usage:
  kitti360_cross_pass.py KITTI360_DIR OUT --query 947 --map 1134 [--bin target/release/infraloc]
      [--ground | --via tiles [--crs EPSG:N] [--offset E,N,H] [--tile-res M]]
Then:
  infraloc refine --camera OUT/camera.yaml --image KITTI360_DIR/image_00/0000000947.png \\
      --points OUT/map.csv --init OUT/truth.json --starts 3 --report OUT/report.json
or, with --via tiles (refine's default --radius 25 m holds too little of one front-half sweep's
ground for the tile check, which wants 10 % of the disc valid; 20 m passes for 947↔1134):
  infraloc refine --camera OUT/camera.yaml --image KITTI360_DIR/image_00/0000000947.png \\
      --tiles OUT/tiles --radius 20 --init OUT/truth.json --starts 3 --report OUT/report.json
Needs numpy and cv2 (cv2 only for the nearest-neighbour figure; without it that figure is
left out).
"""
import argparse
import json
import os
import shutil
import subprocess
import sys

import numpy as np

# `refine --starts 3`'s starts as offsets from --init: x, y, z (m, map frame), yaw (deg).
# START_SPREAD = (0.2 m on a circle, 0.1 m height alternately, 1° yaw) at phases 0 and π.
STARTS = [(0.0, 0.0, 0.0, 0.0), (0.2, 0.0, 0.1, 1.0), (-0.2, 0.0, -0.1, 1.0)]
# --via tiles: KITTI-360's world origin (the devkit's origin_oxts, lat 48.9843445, lon 8.4295857)
# in UTM 32N by pyproj, as docs/map.md and tests/it/tile_scans.rs place it; heights kept.
CRS = "EPSG:32632"
OFFSET = (458265.478, 5425872.189, 0.0)
# The tile box's margin around the scan and the two cameras, m: more than refine's default
# --radius (25 m) plus its search box (1 m).
TILE_MARGIN_M = 30.0
# The tile's resolution, m (`tile scans --res`): at the default 0.1 m one sweep's rings leave
# ~97 % of the cells within 25 m of the camera empty (tests/it/tile_scans.rs uses 0.25 m too).
TILE_RES = 0.25


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


def orthonormal(r, what="R_rect_00"):
    u, _, vt = np.linalg.svd(r)
    q = u @ vt
    if np.linalg.det(q) < 0:
        sys.exit(f"{what} is not near a rotation")
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


def pose_json(cam_from_map, note, crs="LOCAL"):
    """An infraloc.pose.v1 pose-like JSON (what `refine --init` reads) for a 4×4 cam←map."""
    return {
        "schema": "infraloc.pose.v1",
        "crs": crs,
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


def tile_inputs(a, xyz_world, cams_xy_world):
    """M's scan → `infraloc tile scans` → OUT/tiles/kitti360-M, in `--crs` with `--offset`.

    The product places KITTI-360's world frame in the projected CRS by adding the offset to every
    point (docs/map.md "From a drive's scans to a tile"): map = world + offset. The box is the
    scan's extent and both cameras' positions, widened by `TILE_MARGIN_M` on every side, so that
    `refine --tiles` finds the tile covering the query camera with its whole --radius disc inside
    (the scan itself sees only ahead of the map car). Returns the command and the tile's id."""
    off = np.array(a.offset)
    xy = np.vstack([xyz_world[:, :2], cams_xy_world]) + off[:2]
    lo, hi = xy.min(axis=0) - TILE_MARGIN_M, xy.max(axis=0) + TILE_MARGIN_M
    # Whole multiples of --res, so the grid's edges are round numbers in the CRS.
    lo, hi = np.floor(lo / a.tile_res) * a.tile_res, np.ceil(hi / a.tile_res) * a.tile_res
    tid = f"kitti360-{a.map}"
    tiles = os.path.join(a.out, "tiles")
    # A fresh cache: a tile left from another map in OUT would compete for the camera.
    if os.path.isdir(tiles):
        shutil.rmtree(tiles)
    k = a.kitti360
    cmd = [a.bin, "tile", "scans", "--out", tiles, "--id", tid,
           "--poses", os.path.join(k, "poses", "poses.txt"), "--calib", os.path.join(k, "calibration"),
           "--crs", a.crs, "--offset", ",".join(f"{v:.3f}" for v in off),
           "--bbox", ",".join(f"{v:.2f}" for v in (lo[0], lo[1], hi[0], hi[1])),
           "--res", f"{a.tile_res:g}",
           os.path.join(k, "velodyne", f"{a.map:010d}.bin")]
    print("+ " + " ".join(cmd), file=sys.stderr)
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    return cmd, tid


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("kitti360", help="KITTI-360 sample dir (calibration/, image_00/, velodyne/, poses/)")
    ap.add_argument("out")
    ap.add_argument("--query", type=int, required=True, help="frame whose camera is localized")
    ap.add_argument("--map", type=int, required=True, help="frame whose scan is the map")
    ap.add_argument("--bin", default="target/release/infraloc")
    ap.add_argument("--ground", action="store_true", help="keep only a crude ground band of the scan")
    ap.add_argument("--via", choices=["points", "tiles"], default="points",
                    help="the map as a world-frame CSV for `refine --points` (default) or as a "
                         "tile by `tile scans` for `refine --tiles`")
    ap.add_argument("--crs", default=CRS, help=f"--via tiles: the tile's CRS (default {CRS})")
    ap.add_argument("--offset", default=",".join(f"{v:.3f}" for v in OFFSET),
                    type=lambda v: tuple(float(x) for x in v.split(",")),
                    help="--via tiles: the world frame's origin in --crs, E,N,H "
                         f"(default {','.join(f'{v:.3f}' for v in OFFSET)})")
    ap.add_argument("--tile-res", type=float, default=TILE_RES,
                    help=f"--via tiles: the tile's resolution, m (default {TILE_RES:g})")
    a = ap.parse_args()
    if a.via == "tiles" and a.ground:
        sys.exit("--ground is for --via points: a tile keeps the ground its own filter finds")
    if len(a.offset) != 3:
        sys.exit("--offset: three numbers E,N,H")
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
    cam_m_world = (ps[a.map] @ c2p @ np.linalg.inv(rect))[:3, 3]
    if a.via == "tiles":
        # The map frame is the tile's: world + offset, the camera centre moved by it. The rotation
        # is orthonormalised first (KITTI-360's 10 digits leave ~1e-10): with a translation of
        # ~5e6 m, `refine`'s own orthonormalisation would otherwise move the centre by ~0.1 mm.
        tile_cmd, tile_id = tile_inputs(a, xyz, np.array([cam_to_world[:2, 3], cam_m_world[:2]]))
        r = orthonormal(truth[:3, :3], "the query camera's rotation")
        truth_map, crs = np.eye(4), a.crs
        truth_map[:3, :3] = r
        truth_map[:3, 3] = -r @ (cam_to_world[:3, 3] + np.array(a.offset))
        frame = f"{a.crs}, KITTI-360's world frame + ({', '.join(f'{v:.3f}' for v in a.offset)})"
    else:
        with open(os.path.join(a.out, "map.csv"), "w") as f:
            f.write("x,y,z,reflectivity\n")
            for (x, y, z), r in zip(xyz, refl):
                f.write(f"{x:.4f},{y:.4f},{z:.4f},{r}\n")
        truth_map, crs, frame = truth, "LOCAL", "the world frame"

    note = (f"KITTI-360 drive 0000 frame {a.query}'s rectified image_00 in {frame} "
            f"(cam0_to_world); map from frame {a.map}'s scan")
    json.dump(pose_json(truth_map, note, crs), open(os.path.join(a.out, "truth.json"), "w"), indent=2)
    for n, (dx, dy, dz, dyaw) in enumerate(STARTS, 1):
        s = pose_json(perturbed(truth_map, dx, dy, dz, dyaw),
                      f"{note}; start {n}: truth moved ({dx:+.2f}, {dy:+.2f}, {dz:+.2f}) m, yaw {dyaw:+.1f}°",
                      crs)
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
    cq, cm = cam_to_world[:3, 3], cam_m_world
    fq, fm = cam_to_world[:3, 2], (ps[a.map] @ c2p)[:3, 2]
    d = cm - cq
    heading = np.degrees(np.arctan2(fm[1], fm[0]) - np.arctan2(fq[1], fq[0]))
    heading = (heading + 180.0) % 360.0 - 180.0
    fwd = fq[:2] / np.linalg.norm(fq[:2])
    info = {
        "query": a.query,
        "map": a.map,
        "via": a.via,
        # The sweep's points (the figures below); with --via tiles the map is its tile instead.
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
    if a.via == "tiles":
        info["tile"] = {"id": tile_id, "crs": a.crs, "offset": list(a.offset), "res_m": a.tile_res,
                        "command": tile_cmd[1:]}
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
