#!/usr/bin/env python3
"""Point clouds written by other projects' writers, and the rasters `tile build` must make of them.

Usage: cloud_reference.py OUTDIR

A seeded synthetic street (ETRS89 / UTM 32N, EPSG:25832): a sloping road with bright lane
stripes, parked cars, people, a tree, and low-noise points (LAS class 7) below the road. Written as

- street.laz       laspy + lazrs, LAS 1.4 point format 7 (RGB), 16-bit intensity, LAS classes
                   (2 ground, 1 cars/people, 5 tree, 7 noise), CRS as an OGC WKT VLR;
- street.copc.laz  copclib (COPC), the same points in a level-2 octree;
- street.pcd       binary PCD (PCL spec v0.7: x y z float64, intensity float32 0..255), no
                   classes, no CRS, no noise points;
- split/           the same PCD as an Autoware split map (20 m grid files + metadata yaml);

and the numpy references (raw little-endian arrays + JSON):

- ref_class.json/.u8/.f32  reflectivity and height from the LAS class 2 points: per 0.1 m cell the
                           median of intensity·255/65535 (rounded half to even, clipped 1..255,
                           0 = no ground), the median of float32 heights (NaN = no ground);
- ref_filter.*             the same from the PCD's points through the lowest-surface filter: the
                           lowest float32 height per 0.5 m cell, opened (min then max over a
                           square of ±12 cells, empty cells ignored), ground = z ≤ surface + 0.2;
- ref_rgb.u8               colour of the highest point per cell (16-bit / 257, rounded).
"""
import json
import os
import sys

import laspy
import numpy as np
import pyproj

OUT = sys.argv[1]
os.makedirs(OUT, exist_ok=True)
rng = np.random.default_rng(20261128)

EPSG = 25832
X0, Y0 = 691_000.0, 5_335_000.0  # Munich area
SIZE = 60.0  # data extent, metres
TILE = [X0 + 15.0, Y0 + 15.0, X0 + 45.0, Y0 + 45.0]  # the box asked for
RES, CELL, WINDOW, TOL = 0.1, 0.5, 12.0, 0.2


def ground_z(x, y):
    return 520.0 + 0.02 * (x - X0) + 0.01 * (y - Y0)


# Ground: ~300 points/m², a few mm of noise; stripes every 3.5 m are bright.
n = int(SIZE * SIZE * 300)
gx = X0 + rng.uniform(0, SIZE, n)
gy = Y0 + rng.uniform(0, SIZE, n)
gz = ground_z(gx, gy) + rng.normal(0, 0.005, n)
stripe = ((gx - X0) % 3.5) < 0.15
gi = np.where(stripe, rng.normal(52000, 3000, n), rng.normal(15000, 4000, n))
gi = np.clip(gi, 1, 65535).astype(np.uint16)
gc = np.full(n, 2, np.uint8)

parts = [(gx, gy, gz, gi, gc)]
# Parked cars (4.5 x 1.8 m, roof 1.5 m): points on roof and sides, class 1.
for cx, cy in [(X0 + 20, Y0 + 25), (X0 + 27, Y0 + 25), (X0 + 34, Y0 + 40), (X0 + 40, Y0 + 18)]:
    m = 6000
    x = cx + rng.uniform(0, 4.5, m)
    y = cy + rng.uniform(0, 1.8, m)
    z = ground_z(x, y) + rng.uniform(0.3, 1.5, m)
    parts.append((x, y, z, rng.integers(2000, 60000, m).astype(np.uint16), np.full(m, 1, np.uint8)))
# People (0.5 m wide, 1.8 m tall).
for px, py in [(X0 + 22, Y0 + 31), (X0 + 30, Y0 + 33)]:
    m = 800
    x = px + rng.uniform(0, 0.5, m)
    y = py + rng.uniform(0, 0.5, m)
    z = ground_z(x, y) + rng.uniform(0.1, 1.8, m)
    parts.append((x, y, z, rng.integers(2000, 60000, m).astype(np.uint16), np.full(m, 1, np.uint8)))
# A tree: a trunk and a 6 m canopy 3–7 m up (the ground under it is scanned too), class 5.
m = 20000
a = rng.uniform(0, 2 * np.pi, m)
r = 3.0 * np.sqrt(rng.uniform(0, 1, m))
x = X0 + 37 + r * np.cos(a)
y = Y0 + 30 + r * np.sin(a)
z = ground_z(x, y) + rng.uniform(3.0, 7.0, m)
parts.append((x, y, z, rng.integers(2000, 60000, m).astype(np.uint16), np.full(m, 5, np.uint8)))
# Low noise (multipath) 2–5 m below the road, class 7: dropped on read.
m = 50
x = X0 + rng.uniform(0, SIZE, m)
y = Y0 + rng.uniform(0, SIZE, m)
z = ground_z(x, y) - rng.uniform(2, 5, m)
parts.append((x, y, z, rng.integers(2000, 60000, m).astype(np.uint16), np.full(m, 7, np.uint8)))

X = np.concatenate([p[0] for p in parts])
Y = np.concatenate([p[1] for p in parts])
Z = np.concatenate([p[2] for p in parts])
I = np.concatenate([p[3] for p in parts])
C = np.concatenate([p[4] for p in parts])
perm = rng.permutation(len(X))
X, Y, Z, I, C = X[perm], Y[perm], Z[perm], I[perm], C[perm]
RGB = np.stack(
    [
        (40000 + 20000 * np.sin(X)).astype(np.uint16),
        (30000 + 20000 * np.cos(Y)).astype(np.uint16),
        (I // 2 + 1000).astype(np.uint16),
    ]
)

# --- LAZ (laspy + lazrs) ---
header = laspy.LasHeader(point_format=7, version="1.4")
header.scales = np.array([0.001, 0.001, 0.001])
header.offsets = np.array([X0, Y0, 500.0])
header.add_crs(pyproj.CRS.from_epsg(EPSG))
las = laspy.LasData(header)
las.x, las.y, las.z = X, Y, Z
las.intensity = I
las.classification = C
las.red, las.green, las.blue = RGB
las.write(os.path.join(OUT, "street.laz"))
# What the file holds (after quantisation to its 1 mm grid).
back = laspy.read(os.path.join(OUT, "street.laz"))
X, Y, Z = np.asarray(back.x), np.asarray(back.y), np.asarray(back.z)
I = np.asarray(back.intensity)
C = np.asarray(back.classification)
RGB = np.stack([np.asarray(back.red), np.asarray(back.green), np.asarray(back.blue)])

# --- COPC (copclib): the same records in the level-2 voxels of a cube around the data ---
import copclib as copc  # noqa: E402

half = 40.0
center = (X0 + 30.0, Y0 + 30.0, 530.0)
cfg = copc.CopcConfigWriter(
    7, copc.Vector3(0.001, 0.001, 0.001), copc.Vector3(X0, Y0, 500.0), pyproj.CRS.from_epsg(EPSG).to_wkt("WKT1_GDAL")
)
cfg.copc_info.center_x, cfg.copc_info.center_y, cfg.copc_info.center_z = center
cfg.copc_info.halfsize = half
cfg.copc_info.spacing = 1.0
lh = cfg.las_header
lh.min = copc.Vector3(X.min(), Y.min(), Z.min())
lh.max = copc.Vector3(X.max(), Y.max(), Z.max())
writer = copc.FileWriter(os.path.join(OUT, "street.copc.laz"), cfg)
records = back.points.array
level = 2
cells = 1 << level
vx = np.floor((X - (center[0] - half)) / (2 * half) * cells).astype(int)
vy = np.floor((Y - (center[1] - half)) / (2 * half) * cells).astype(int)
vz = np.floor((Z - (center[2] - half)) / (2 * half) * cells).astype(int)
assert vx.min() >= 0 and vy.min() >= 0 and vz.min() >= 0 and max(vx.max(), vy.max(), vz.max()) < cells
key = (vx * cells + vy) * cells + vz
for k in np.unique(key):
    sel = key == k
    data = records[sel].tobytes()
    writer.AddNode(
        copc.VoxelKey(level, int(k // (cells * cells)), int(k // cells % cells), int(k % cells)),
        copc.VectorChar(np.frombuffer(data, np.int8)),
    )
writer.Close()

# --- PCD (PCL spec, binary), unclassified, 8-bit intensities as float32 ---
I8 = np.round(I.astype(np.float64) * 255.0 / 65535.0).astype(np.float32)
keep = C != 7  # a PCD map has no noise classes to drop: leave the noise out
# x y z as float64 (PCL's TYPE F SIZE 8): float32 cannot hold UTM eastings to a millimetre.
pcd = np.zeros(keep.sum(), dtype=[("x", "<f8"), ("y", "<f8"), ("z", "<f8"), ("intensity", "<f4")])
pcd["x"], pcd["y"], pcd["z"] = X[keep], Y[keep], Z[keep]
pcd["intensity"] = I8[keep]


def write_pcd(path, arr):
    head = (
        "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS x y z intensity\n"
        "SIZE 8 8 8 4\nTYPE F F F F\nCOUNT 1 1 1 1\n"
        f"WIDTH {len(arr)}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {len(arr)}\nDATA binary\n"
    )
    with open(path, "wb") as f:
        f.write(head.encode())
        f.write(arr.tobytes())


write_pcd(os.path.join(OUT, "street.pcd"), pcd)
os.makedirs(os.path.join(OUT, "split"), exist_ok=True)
meta = ["x_resolution: 20.0", "y_resolution: 20.0"]
gxk = np.floor(pcd["x"] / 20.0).astype(int)
gyk = np.floor(pcd["y"] / 20.0).astype(int)
for a_, b_ in sorted(set(zip(gxk.tolist(), gyk.tolist()))):
    sel = (gxk == a_) & (gyk == b_)
    name = f"{a_ * 20}_{b_ * 20}.pcd"
    write_pcd(os.path.join(OUT, "split", name), pcd[sel])
    meta.append(f"{name}: [{a_ * 20}, {b_ * 20}]")
# A grid file far away that the box must not read: unreadable on purpose.
with open(os.path.join(OUT, "split", "9000_9000.pcd"), "wb") as f:
    f.write(b"not a pcd")
meta.append("9000_9000.pcd: [9000, 9000]")
with open(os.path.join(OUT, "split", "pointcloud_map_metadata.yaml"), "w") as f:
    f.write("\n".join(meta) + "\n")


# --- references ---
def grids(b):
    """The tile grid and read grid exactly as `tile build` snaps them."""
    x0 = np.floor(b[0] / RES) * RES
    y0 = np.ceil(b[3] / RES) * RES
    w = int(np.ceil((b[2] - x0) / RES - 1e-9))
    h = int(np.ceil((y0 - b[1]) / RES - 1e-9))
    ratio = int(round(CELL / RES))
    mc = int(np.ceil(WINDOW / 2 / CELL)) * ratio
    m = mc * RES
    return dict(x0=x0, y0=y0, w=w, h=h, rx0=x0 - m, ry0=y0 + m, mc=mc, ratio=ratio)


def read_cells(g, x, y):
    col = np.floor((x - g["rx0"]) / RES)
    row = np.floor((g["ry0"] - y) / RES)
    return col, row


def rasters(g, col, row, z32, val, ground):
    tc, tr = col - g["mc"], row - g["mc"]
    sel = ground & (tc >= 0) & (tr >= 0) & (tc < g["w"]) & (tr < g["h"])
    cell = (tr[sel] * g["w"] + tc[sel]).astype(np.int64)
    refl = np.zeros(g["w"] * g["h"], np.uint8)
    hgt = np.full(g["w"] * g["h"], np.nan, np.float32)
    # Medians per cell: sort by (cell, value); the middle one or two of each run.
    for src, put in ((val[sel], "refl"), (z32[sel].astype(np.float64), "hgt")):
        order = np.lexsort((src, cell))
        c, v = cell[order], src[order]
        starts = np.flatnonzero(np.r_[True, c[1:] != c[:-1]])
        ends = np.r_[starts[1:], len(c)]
        med = (v[starts + (ends - starts - 1) // 2] + v[starts + (ends - starts) // 2]) / 2.0
        if put == "refl":
            refl[c[starts]] = np.clip(np.round(med), 1, 255)
        else:
            hgt[c[starts]] = med.astype(np.float32)
    return refl, hgt


def save(name, g, refl, hgt, extra=None):
    refl.tofile(os.path.join(OUT, name + ".u8"))
    hgt.astype("<f4").tofile(os.path.join(OUT, name + ".f32"))
    meta = dict(x0=g["x0"], y0=g["y0"], width=g["w"], height=g["h"], res=RES, cells=int((refl > 0).sum()))
    meta.update(extra or {})
    with open(os.path.join(OUT, name + ".json"), "w") as f:
        json.dump(meta, f)


# Classified: LAS class 2, intensity 16-bit full scale.
g = grids(TILE)
col, row = read_cells(g, X, Y)
val = I.astype(np.float64) * 255.0 / 65535.0
refl, hgt = rasters(g, col, row, Z.astype(np.float32), val, C == 2)
save("ref_class", g, refl, hgt)

# Top colour per cell over every point but noise.
tc, tr = col - g["mc"], row - g["mc"]
sel = (C != 7) & (tc >= 0) & (tr >= 0) & (tc < g["w"]) & (tr < g["h"])
idx = np.flatnonzero(sel)
cell = (tr[idx] * g["w"] + tc[idx]).astype(np.int64)
z32 = Z[idx].astype(np.float32)
# Highest z per cell, the first in file order among equals.
order = np.lexsort((idx, -z32.astype(np.float64), cell))
first = np.r_[True, cell[order][1:] != cell[order][:-1]]
top = idx[order][first]
rgb = np.zeros((g["w"] * g["h"], 3), np.uint8)
rgb[cell[order][first]] = np.round(RGB[:, top].T.astype(np.float64) / 257.0).astype(np.uint8)
rgb.tofile(os.path.join(OUT, "ref_rgb.u8"))

# Filter: the PCD's points, 8-bit intensity.
g = grids(TILE)
px, py, pz, pv = (pcd[k].astype(np.float64) for k in ("x", "y", "z", "intensity"))
col, row = read_cells(g, px, py)
rw, rh = g["w"] + 2 * g["mc"], g["h"] + 2 * g["mc"]
inside = (col >= 0) & (row >= 0) & (col < rw) & (row < rh)
ratio = g["ratio"]
gw, gh = -(-rw // ratio), -(-rh // ratio)
low = np.full(gw * gh, np.inf, np.float32)
gc_ = ((row[inside] // ratio) * gw + col[inside] // ratio).astype(np.int64)
z32 = pcd["z"].astype(np.float32)
np.minimum.at(low, gc_, z32[inside])
low = low.reshape(gh, gw)
r = int(round(WINDOW / 2 / CELL))


def filt(a, fill, op):
    out = a
    for axis in (1, 0):
        pad = [(0, 0), (0, 0)]
        pad[axis] = (r, r)
        p = np.pad(out, pad, constant_values=fill)
        win = np.lib.stride_tricks.sliding_window_view(p, 2 * r + 1, axis=axis)
        out = op(win, axis=-1)
    return out


eroded = filt(low, np.inf, np.min)
opened = filt(np.where(np.isfinite(eroded), eroded, -np.inf), -np.inf, np.max)
opened = np.where(np.isfinite(opened), opened, np.inf).astype(np.float32).ravel()
surf = np.full(len(px), np.inf, np.float32)
surf[inside] = opened[gc_]
ground = inside & (z32.astype(np.float64) <= surf.astype(np.float64) + TOL)
refl, hgt = rasters(g, col, row, z32, pv, ground)
save("ref_filter", g, refl, hgt)
print(json.dumps(dict(points=len(X), pcd_points=int(keep.sum()))))
