#!/usr/bin/env python3
"""The LAS version matrix of tests/it/las_versions.rs, written by laspy (+ lazrs for LAZ).

Usage: las_matrix.py OUT_DIR

The same 3000 points (a 20 m x 20 m patch in ETRS89 / UTM 32N, EPSG:25832: a ground plane of
class 2 with a stripe of bright intensity, and class 1 points above it) are written as LAS 1.0,
1.1, 1.2, 1.3 and 1.4, each with its CRS as GeoTIFF keys, as a WKT VLR, or absent, each plain
and LAZ; then once in every point format 0-10 (GeoTIFF keys, at the lowest version that has the
format), formats 1 and 6 also with extra bytes. laspy writes LAS 1.1-1.4; a 1.0 file is laspy's
1.1 file with the version byte set to 0 (the two headers have the same layout; 1.0 calls the file
source id "reserved"). Prints a JSON manifest: [{"file", "version", "format", "crs", "laz"}].
"""
import json
import os
import struct
import sys

import laspy
import numpy as np

OUT = sys.argv[1]
os.makedirs(OUT, exist_ok=True)
X0, Y0 = 691000.0, 5335000.0
N = 3000
rng = np.random.default_rng(66)
x = X0 + rng.uniform(0, 20, N)
y = Y0 + rng.uniform(0, 20, N)
ground = rng.uniform(0, 1, N) < 0.7
z = 512.0 + 0.05 * (x - X0) + np.where(ground, 0.0, rng.uniform(0.5, 3.0, N))
intensity = np.where((y - Y0 > 8) & (y - Y0 < 10), 50000, 9000).astype(np.uint16)
intensity += rng.integers(0, 500, N).astype(np.uint16)
cls = np.where(ground, 2, 1).astype(np.uint8)

WKT = ('PROJCS["ETRS89 / UTM zone 32N",GEOGCS["ETRS89",DATUM["European_Terrestrial_Reference_'
       'System_1989",SPHEROID["GRS 1980",6378137,298.257222101,AUTHORITY["EPSG","7019"]],'
       'AUTHORITY["EPSG","6258"]],PRIMEM["Greenwich",0],UNIT["degree",0.0174532925199433],'
       'AUTHORITY["EPSG","4258"]],PROJECTION["Transverse_Mercator"],PARAMETER["latitude_of_origin",0],'
       'PARAMETER["central_meridian",9],PARAMETER["scale_factor",0.9996],PARAMETER["false_easting",'
       '500000],PARAMETER["false_northing",0],UNIT["metre",1,AUTHORITY["EPSG","9001"]],'
       'AUTHORITY["EPSG","25832"]]')
# GeoKeyDirectory 1.1.0: projected model, PixelIsArea, EPSG:25832, linear unit metre.
KEYS = struct.pack("<20H", 1, 1, 0, 4, 1024, 0, 1, 1, 1025, 0, 1, 1, 3072, 0, 1, 25832,
                   3076, 0, 1, 9001)


def write(path, version, fmt, crs, laz, extra=False):
    v = "1.1" if version == "1.0" else version
    h = laspy.LasHeader(point_format=fmt, version=v)
    h.scales = [0.001, 0.001, 0.001]
    h.offsets = [X0, Y0, 500.0]
    if extra:
        h.add_extra_dim(laspy.ExtraBytesParams(name="deviation", type=np.uint16))
        h.add_extra_dim(laspy.ExtraBytesParams(name="confidence", type=np.float32))
    if crs == "geotiff":
        h.vlrs.append(laspy.VLR("LASF_Projection", 34735, "GeoKeyDirectoryTag", KEYS))
    elif crs == "wkt":
        h.vlrs.append(laspy.VLR("LASF_Projection", 2112, "OGC WKT", WKT.encode() + b"\0"))
        if v == "1.4":
            h.global_encoding.wkt = True
    las = laspy.LasData(h)
    las.x, las.y, las.z = x, y, z
    las.intensity = intensity
    las.classification = cls
    if "red" in las.point_format.dimension_names:
        las.red = las.green = las.blue = np.full(N, 30000, np.uint16)
    if extra:
        las.deviation = np.arange(N, dtype=np.uint16)
        las.confidence = np.linspace(0, 1, N).astype(np.float32)
    las.write(path, laz_backend=laspy.LazBackend.Lazrs if laz else None)
    if version == "1.0":
        with open(path, "r+b") as f:
            f.seek(25)
            f.write(b"\0")


rows = []
for version in ["1.0", "1.1", "1.2", "1.3", "1.4"]:
    fmt = {"1.0": 1, "1.1": 0, "1.2": 3, "1.3": 1, "1.4": 6}[version]
    for crs in ["geotiff", "wkt", "none"]:
        for laz in [False, True]:
            name = f"v{version}_pf{fmt}_{crs}.{'laz' if laz else 'las'}"
            write(os.path.join(OUT, name), version, fmt, crs, laz)
            rows.append(dict(file=name, version=version, format=fmt, crs=crs, laz=laz))
lowest = {0: "1.0", 1: "1.0", 2: "1.2", 3: "1.2", 4: "1.3", 5: "1.3"}
for fmt in range(11):
    version = lowest.get(fmt, "1.4")
    for extra in ([False, True] if fmt in (1, 6) else [False]):
        # LAZ has no compressor for the waveform formats (4, 5, 9, 10).
        laz = fmt not in (4, 5, 9, 10)
        name = f"pf{fmt}{'_extra' if extra else ''}.{'laz' if laz else 'las'}"
        write(os.path.join(OUT, name), version, fmt, "geotiff", laz, extra)
        rows.append(dict(file=name, version=version, format=fmt, crs="geotiff", laz=laz))
print(json.dumps(rows))
