#!/usr/bin/env python3
"""Reference WGS84 <-> national-grid coordinates from pyproj (PROJ), for tests/it/geo_national_grids.rs.

Writes tests/data/geo/national_pyproj.csv with columns epsg,lat,lon,x,y,ilat,ilon: (lat, lon) in
degrees projected by pyproj into EPSG:epsg with PROJ's default operation (no datum grids
installed, so a datum other than WGS84 is reached through the operation's Helmert parameters),
and (ilat, ilon) pyproj's inverse of (x, y) as written. The two differ where the datum shift is
a 3-D Helmert on 2-D points (PROJ keeps the height of each side at 0: CH1903+ 1.3 mm, RD New
0.6 mm), so the inverse is compared with pyproj's inverse, not with (lat, lon). Each CRS gets a
9 x 9 grid over its EPSG area of use.

CRSs: Amersfoort / RD New (28992); CH1903+ / LV95 (2056); CH1903 / LV03 (21781); ETRS89 / UTM 28N..38N (25828-25838);
RGF93 / Lambert-93 (2154); ETRF2000-PL / CS92 (2180, tmerc); NAD83 State Planes in metres: New
York Long Island (32118), California zone 3 (26943), Texas Central (32139).

Run: python3 tests/reference/make_national_grid_refs.py   (from the repository root)
"""
import csv
import os

import numpy as np
import pyproj

OUT = os.path.join(os.path.dirname(__file__), "..", "data", "geo", "national_pyproj.csv")
CODES = [28992, 2056, 21781] + list(range(25828, 25839)) + [2154, 2180, 32118, 26943, 32139]
N = 9


def main():
    rows = []
    for code in CODES:
        crs = pyproj.CRS.from_epsg(code)
        w, s, e, n = crs.area_of_use.bounds
        t = pyproj.Transformer.from_crs("EPSG:4326", crs, always_xy=True)
        for lat in np.linspace(s, n, N):
            for lon in np.linspace(w, e, N):
                x, y = t.transform(lon, lat)
                if np.isfinite(x) and np.isfinite(y):
                    x, y = float(f"{x:.6f}"), float(f"{y:.6f}")
                    ilon, ilat = t.transform(x, y, direction="INVERSE")
                    rows.append((code, float(lat), float(lon), x, y, ilat, ilon))
    os.makedirs(os.path.dirname(OUT), exist_ok=True)
    with open(OUT, "w", newline="") as f:
        wr = csv.writer(f, lineterminator="\n")
        wr.writerow(["epsg", "lat", "lon", "x", "y", "ilat", "ilon"])
        for code, lat, lon, x, y, ilat, ilon in rows:
            wr.writerow([code, repr(lat), repr(lon), f"{x:.6f}", f"{y:.6f}", f"{ilat:.10f}", f"{ilon:.10f}"])
    print(f"{len(rows)} rows -> {OUT} (pyproj {pyproj.__version__}, PROJ {pyproj.proj_version_str})")


if __name__ == "__main__":
    main()
