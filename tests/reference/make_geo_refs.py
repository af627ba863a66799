#!/usr/bin/env python3
"""Reference WGS84 <-> UTM coordinates from pyproj (PROJ), for tests/it/geo_reference.rs.

Writes tests/data/geo/utm_pyproj.csv with columns epsg,lat,lon,x,y: (lat, lon) in degrees projected
by pyproj into EPSG:epsg. The grid covers every zone of both hemispheres, latitudes -80..84, points
on and around the central meridian, on the zone edges (+-3 deg) and well inside the neighbour zones
(+-4.5, +-6, +-9 deg from the central meridian), and the equator projected into both hemispheres.

Run: python3 tests/reference/make_geo_refs.py   (from the repository root)
"""
import csv
import os

import pyproj

OUT = os.path.join(os.path.dirname(__file__), "..", "data", "geo", "utm_pyproj.csv")

# Latitudes of the global grid (UTM is defined on -80..84).
LATS = [-80.0 + 8.0 * i for i in range(21)] + [84.0, -79.9, 83.9, 45.123456789, -33.87654321]
# Offsets from the central meridian, degrees: centre, inside, edge, just across, neighbour zones.
OFFSETS = [0.0, -1.5, 2.25, -2.999999, 3.0, -3.0, 3.000001, -4.5, 6.0, -9.0]
# Near the equator each point is projected into both the north and the south zone.
EQUATOR_LATS = [0.0, 1e-9, -1e-9, 0.5, -0.5, 4.0, -4.0]


def wrap(lon):
    return (lon + 180.0) % 360.0 - 180.0


def main():
    rows = []
    transformers = {}

    def add(epsg, lat, lon):
        t = transformers.get(epsg)
        if t is None:
            t = pyproj.Transformer.from_crs("EPSG:4326", f"EPSG:{epsg}", always_xy=True)
            transformers[epsg] = t
        x, y = t.transform(lon, lat)
        rows.append((epsg, lat, lon, x, y))

    for zone in range(1, 61):
        cm = -183.0 + 6.0 * zone
        for off in OFFSETS:
            lon = wrap(cm + off)
            for lat in LATS:
                epsg = (32600 if lat >= 0 else 32700) + zone
                add(epsg, lat, lon)
            for lat in EQUATOR_LATS:
                add(32600 + zone, lat, lon)
                add(32700 + zone, lat, lon)

    os.makedirs(os.path.dirname(OUT), exist_ok=True)
    with open(OUT, "w", newline="") as f:
        w = csv.writer(f, lineterminator="\n")
        w.writerow(["epsg", "lat", "lon", "x", "y"])
        for epsg, lat, lon, x, y in rows:
            # repr() round-trips f64 exactly; metres to 1e-6 m are far below the 1 mm tolerance.
            w.writerow([epsg, repr(lat), repr(lon), f"{x:.6f}", f"{y:.6f}"])
    print(f"{len(rows)} rows -> {OUT} (pyproj {pyproj.__version__}, PROJ {pyproj.proj_version_str})")


if __name__ == "__main__":
    main()
