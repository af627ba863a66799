#!/usr/bin/env python3
"""Reference WGS84 <-> national-grid coordinates from pyproj (PROJ), for tests/it/geo_national_grids.rs.

Writes tests/data/geo/national_pyproj.csv with columns epsg,lat,lon,x,y: (lat, lon) in degrees
projected by pyproj into EPSG:epsg with PROJ's default operation (no datum grids installed, so a
datum other than WGS84 is reached through the operation's Helmert parameters). Each CRS gets a
9 x 9 grid over its EPSG area of use.

CRSs: Amersfoort / RD New (28992); ETRS89 / UTM 28N..38N (25828-25838); RGF93 / Lambert-93 (2154);
NAD83 State Planes in metres: New York Long Island (32118), California zone 3 (26943), Texas
Central (32139).

Run: python3 tests/reference/make_national_grid_refs.py   (from the repository root)
"""
import csv
import os

import numpy as np
import pyproj

OUT = os.path.join(os.path.dirname(__file__), "..", "data", "geo", "national_pyproj.csv")
CODES = [28992] + list(range(25828, 25839)) + [2154, 32118, 26943, 32139]
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
                    rows.append((code, float(lat), float(lon), x, y))
    os.makedirs(os.path.dirname(OUT), exist_ok=True)
    with open(OUT, "w", newline="") as f:
        wr = csv.writer(f, lineterminator="\n")
        wr.writerow(["epsg", "lat", "lon", "x", "y"])
        for code, lat, lon, x, y in rows:
            wr.writerow([code, repr(lat), repr(lon), f"{x:.6f}", f"{y:.6f}"])
    print(f"{len(rows)} rows -> {OUT} (pyproj {pyproj.__version__}, PROJ {pyproj.proj_version_str})")


if __name__ == "__main__":
    main()
