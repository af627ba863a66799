#!/usr/bin/env python3
"""Reference rasters for `tile build` on other writers' survey files (tests/it/survey_corpus.rs).

Usage: survey_reference.py JOBS.json OUT_DIR

JOBS.json is a list of {"name", "file", "src": CRS of the file's coordinates as pyproj takes it
(an EPSG code or a WKT), "tile": the tile's EPSG code, "z": metres per vertical unit, "res" and
"cell": the tile's and the ground filter's cell, metres}. For each
job the file is read whole with laspy (+ lazrs), its points put into the tile's CRS with pyproj
(heights × z), noise (classes 7, 18) dropped, and the tile computed as `tile build` defines it
(docs/map.md): the points' own extent snapped outward to RES, ground = LAS class 2 if the file
has any, else the lowest surface of each ground cell opened with the window, the median
normalised intensity and the median height per cell. Writes NAME.u8, NAME.f32 and NAME.json
(grid, point count, extent, and the largest difference between pyproj and a pure scale-and-shift
of the coordinates, which is what a unit conversion within one projection must be).
"""
import json
import os
import sys

import laspy
import numpy as np
import pyproj

WINDOW, TOL = 12.0, 0.2

jobs = json.load(open(sys.argv[1]))
OUT = sys.argv[2]
os.makedirs(OUT, exist_ok=True)


def grids(b):
    x0 = np.floor(b[0] / RES) * RES
    y0 = np.ceil(b[3] / RES) * RES
    w = int(np.ceil((b[2] - x0) / RES - 1e-9))
    h = int(np.ceil((y0 - b[1]) / RES - 1e-9))
    ratio = int(round(CELL / RES))
    mc = int(np.ceil(WINDOW / 2 / CELL)) * ratio
    m = mc * RES
    return dict(x0=x0, y0=y0, w=w, h=h, rx0=x0 - m, ry0=y0 + m, mc=mc, ratio=ratio)


def medians(cell, src, n):
    order = np.lexsort((src, cell))
    c, v = cell[order], src[order]
    starts = np.flatnonzero(np.r_[True, c[1:] != c[:-1]])
    ends = np.r_[starts[1:], len(c)]
    med = (v[starts + (ends - starts - 1) // 2] + v[starts + (ends - starts) // 2]) / 2.0
    return c[starts], med


def opened_surface(g, col, row, z32):
    """The lowest z per ground cell, opened (erosion then dilation) with the window."""
    rw, rh = g["w"] + 2 * g["mc"], g["h"] + 2 * g["mc"]
    ratio = g["ratio"]
    gw, gh = -(-rw // ratio), -(-rh // ratio)
    low = np.full(gw * gh, np.inf, np.float32)
    gc = ((row // ratio) * gw + col // ratio).astype(np.int64)
    np.minimum.at(low, gc, z32)
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

    eroded = filt(low.reshape(gh, gw), np.inf, np.min)
    opened = filt(np.where(np.isfinite(eroded), eroded, -np.inf), -np.inf, np.max)
    opened = np.where(np.isfinite(opened), opened, np.inf).astype(np.float32).ravel()
    return opened[gc]


for job in jobs:
    RES, CELL = job["res"], job["cell"]
    las = laspy.read(job["file"])
    n_all = len(las.points)
    x0, y0, z0 = (np.asarray(las.x), np.asarray(las.y), np.asarray(las.z))
    t = pyproj.Transformer.from_crs(pyproj.CRS.from_user_input(job["src"]),
                                    pyproj.CRS.from_user_input(job["tile"]), always_xy=True)
    X, Y = t.transform(x0, y0)
    Z = z0 * job["z"]
    # A conversion within one projection is x·k + c: fit it, report the largest residual.
    A = np.c_[x0 - x0.mean(), np.ones_like(x0)]
    kx, cx = np.linalg.lstsq(A, X, rcond=None)[0]
    B = np.c_[y0 - y0.mean(), np.ones_like(y0)]
    ky, cy = np.linalg.lstsq(B, Y, rcond=None)[0]
    resid = max(np.abs(A @ [kx, cx] - X).max(), np.abs(B @ [ky, cy] - Y).max())
    C = np.asarray(las.classification)
    I = np.asarray(las.intensity).astype(np.float64)
    keep = (C != 7) & (C != 18)
    X, Y, Z, C, I = X[keep], Y[keep], Z[keep], C[keep], I[keep]
    # `tile build`'s extent: closed, so 1 um on the east and north edges (EXTENT_PAD_M).
    b = [X.min(), Y.min(), X.max() + 1e-6, Y.max() + 1e-6]
    g = grids(b)
    col = np.floor((X - g["rx0"]) / RES)
    row = np.floor((g["ry0"] - Y) / RES)
    z32 = Z.astype(np.float32)
    mx = I.max()
    full = 255.0 if mx <= 255 else float(2 ** int(mx).bit_length() - 1)
    val = I * 255.0 / full
    if (C == 2).any():
        ground = C == 2
    else:
        surf = opened_surface(g, col.astype(np.int64), row.astype(np.int64), z32)
        ground = z32.astype(np.float64) <= surf.astype(np.float64) + TOL
    tc, tr = col - g["mc"], row - g["mc"]
    sel = ground & (tc >= 0) & (tr >= 0) & (tc < g["w"]) & (tr < g["h"])
    cell = (tr[sel] * g["w"] + tc[sel]).astype(np.int64)
    refl = np.zeros(g["w"] * g["h"], np.uint8)
    hgt = np.full(g["w"] * g["h"], np.nan, np.float32)
    c, med = medians(cell, val[sel], g["w"] * g["h"])
    refl[c] = np.clip(np.round(med), 1, 255)
    c, med = medians(cell, z32[sel].astype(np.float64), g["w"] * g["h"])
    hgt[c] = med.astype(np.float32)
    name = job["name"]
    refl.tofile(os.path.join(OUT, name + ".u8"))
    hgt.astype("<f4").tofile(os.path.join(OUT, name + ".f32"))
    meta = dict(x0=g["x0"], y0=g["y0"], width=g["w"], height=g["h"], points=n_all,
                extent=[float(v) for v in b], cells=int((refl > 0).sum()),
                affine_residual_m=float(resid), scale=[float(kx), float(ky)])
    with open(os.path.join(OUT, name + ".json"), "w") as f:
        json.dump(meta, f)
print("ok")
