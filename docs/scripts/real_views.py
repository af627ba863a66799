#!/usr/bin/env python3
"""Every real dev set through the product's `refine`, default settings, three starts: one table.

Issue 65's measurement: on each set below, `infraloc refine --init CALIBRATION --starts 3` with
default settings (the search box, the estimator, the gate all as shipped). `--starts 3` refines
from the calibration and from (+0.2, 0, +0.1) m and (−0.2, 0, −0.1) m with +1° yaw around it
(core/src/localize/refine/optima.rs `self_check_starts`; docs/accuracy.md "The default estimator
from three starts on every real set"). One row per start; per set the tool's own self-check
(`self_check` in the report: do the served answers agree within their combined 3σ).

Sets (inputs made under OUT/inputs by the product and docs/scripts, from DATA = the shared
real data, never copied into the repository):
- gantry-{refl,int}-{4dof,6dof}: TUMTraf S110 south1 (docs/scripts/tumtraf_import.py), Ouster's
  reflectivity channel (CSV) or intensity (the PCD itself); 6-DoF is `--polish`;
- kitti-obj-00000N: the KITTI object frames 000000–000002, one each (`kitti import`);
- kitti360-pooled: KITTI-360's ten frames pooled per pair (`kitti import --drive --pairs-out`,
  `refine --pairs`); kitti360-NNNN: each frame alone (frame 100 has no vehicle pose but needs
  none here: the map is its own sweep);
- cross-Q-in-M: frame Q's camera in a map made from frame M's scan in KITTI-360's world frame
  (docs/scripts/kitti360_cross_pass.py), 947↔1134 and 1280↔1338, both directions; with
  `--cross-via tiles`, cross-Q-in-M-tiles: the same through `tile scans` and `refine --tiles`.

Per start the row gives the verdict as the report states it (`grade` when the report has one;
else `accepted` → precise, refused → refused), σ per axis (`sigma`), the answer's error against
the official calibration (the report's `self_check.starts[].offsets`, answer − calibration: x,
y, z in the map frame, yaw about its up axis; horizontal = √(x² + y²)), and whether the answer
lies within 3σ + (0.10 m, 0.3°) of the calibration on every axis it has a σ for (0.15 m on
KITTI-360 sets; judged for every answer with a σ, counted for served ones).

Usage (from the repository root; resumable: a set whose OUT/runs/SET/run.json exists is not run
again, delete it to rerun; sets run one after the other):
  docs/scripts/real_views.py [BIN [OUT]] [--data DIR] [--only SUBSTR …] [--summary-only]
      [--cross-via points|tiles] [--cross-ground] [--extra "REFINE FLAGS"] [--json FILE]
BIN defaults to target/release/infraloc, OUT to /tmp/real-views, DATA to ../shared/data/real.
Writes OUT/real_views.json (every run of the sets selected, and their summary; --json names
another file, e.g. for an --only or --cross-ground subset) and prints the table (Markdown).
`--cross-ground` runs the cross-pass sets on the map scan's ground band instead (sets
cross-Q-in-M-ground); `--cross-via tiles` runs them through the product's tile path instead (sets
cross-Q-in-M-tiles): M's sweep to `tile scans` in EPSG:32632 at 0.25 m, then `refine --tiles` with
`--radius 20` (CROSS_TILES_RADIUS_M: the default 25 m disc holds too little of one sweep's ground
for the tile check); `--extra` adds refine flags to every run (then not the default settings: give
another OUT).
Needs Python 3 and numpy (cv2 optional, see kitti360_cross_pass.py).
"""
import argparse
import json
import math
import os
import re
import shlex
import subprocess
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
CROSS_PAIRS = [(947, 1134), (1134, 947), (1280, 1338), (1338, 1280)]
KITTI360_FRAMES = [100, 250, 360, 570, 644, 729, 947, 1134, 1280, 1338]
# Tolerance added to 3σ: metres on x, y, z; degrees on the angles.
TOL_M, TOL_M_KITTI360, TOL_DEG = 0.10, 0.15, 0.3
# `--cross-via tiles`: refine's --radius (m) on the one-sweep tiles. One front-half sweep's tile
# (0.25 m, kitti360_cross_pass.py's --tile-res) has valid ground in 7.5–7.7 % of the default 25 m
# disc around 947's and 1134's cameras, below the 10 % `refine --tiles` asks of a tile before it
# uses it (src/map/cache.rs MIN_VALID_FRACTION); 20 m is the widest disc above it for both.
CROSS_TILES_RADIUS_M = 20
AXES = ["x", "y", "z", "yaw", "pitch", "roll"]
STARTS = 3


def sh(cmd, **kw):
    print("+ " + " ".join(shlex.quote(str(c)) for c in cmd), flush=True)
    return subprocess.run([str(c) for c in cmd], **kw)


def prepare(bin_, data, inp, cross_via="points", cross_ground=False):
    """The inputs of every set (each made once). Returns {set name: (refine args, tolerance m)}.
    `cross_via`: the cross-pass map as `--points` (a world-frame CSV) or as `--tiles` (a tile of
    the map scan by `tile scans` in EPSG:32632, kitti360_cross_pass.py --via tiles; refine with
    `--radius CROSS_TILES_RADIUS_M`); `cross_ground`: the map scan's crude ground band only
    (kitti360_cross_pass.py --ground, points only), for comparison."""
    sets = {}
    g = os.path.join(data, "tumtraf_s110_south1")
    gdir = os.path.join(inp, "gantry")
    pcd = os.path.join(g, "1646667310_053239541_s110_lidar_ouster_south.pcd")
    if not os.path.exists(os.path.join(gdir, "reflectivity.csv")):
        sh([sys.executable, os.path.join(HERE, "tumtraf_import.py"),
            os.path.join(g, "calib", "s110_camera_basler_south1_8mm.json"), pcd, gdir], check=True)
    gimg = os.path.join(g, "1646667310_044372291_s110_camera_basler_south1_8mm.jpg")
    for ch, pts in (("refl", os.path.join(gdir, "reflectivity.csv")), ("int", pcd)):
        for dof, extra in (("4dof", []), ("6dof", ["--polish"])):
            sets[f"gantry-{ch}-{dof}"] = (
                ["--camera", os.path.join(gdir, "camera.yaml"), "--image", gimg, "--points", pts,
                 "--init", os.path.join(gdir, "pose.json")] + extra, TOL_M)

    ko = os.path.join(data, "kitti_object")
    for n in ("000000", "000001", "000002"):
        d = os.path.join(inp, f"kitti-obj-{n}")
        img = os.path.join(ko, "image_2", f"{n}.png")
        if not os.path.exists(os.path.join(d, "pose.json")):
            os.makedirs(d, exist_ok=True)
            sh([bin_, "kitti", "import", "--calib", os.path.join(ko, "calib", f"{n}.txt"),
                "--image", img, "--camera-out", os.path.join(d, "camera.yaml"),
                "--pose-out", os.path.join(d, "pose.json")], check=True, stdout=subprocess.DEVNULL)
        sets[f"kitti-obj-{n}"] = (
            ["--camera", os.path.join(d, "camera.yaml"), "--image", img,
             "--points", os.path.join(ko, "velodyne", f"{n}.bin"),
             "--init", os.path.join(d, "pose.json")], TOL_M)

    k3 = os.path.join(data, "kitti360_0000")
    d = os.path.join(inp, "kitti360")
    if not os.path.exists(os.path.join(d, "pairs.txt")):
        os.makedirs(d, exist_ok=True)
        sh([bin_, "kitti", "import", "--calib", k3, "--camera-out", os.path.join(d, "camera.yaml"),
            "--pose-out", os.path.join(d, "pose.json"), "--drive", k3,
            "--pairs-out", os.path.join(d, "pairs.txt")], check=True, stdout=subprocess.DEVNULL)
    cam, pose = os.path.join(d, "camera.yaml"), os.path.join(d, "pose.json")
    sets["kitti360-pooled"] = (
        ["--camera", cam, "--pairs", os.path.join(d, "pairs.txt"), "--init", pose], TOL_M_KITTI360)
    for f in KITTI360_FRAMES:
        sets[f"kitti360-{f:04d}"] = (
            ["--camera", cam, "--image", os.path.join(k3, "image_00", f"{f:010d}.png"),
             "--points", os.path.join(k3, "velodyne", f"{f:010d}.bin"), "--init", pose],
            TOL_M_KITTI360)

    suffix = ("-tiles" if cross_via == "tiles" else "") + ("-ground" if cross_ground else "")
    for q, m in CROSS_PAIRS:
        d = os.path.join(inp, f"cross-{q}-in-{m}{suffix}")
        if not os.path.exists(os.path.join(d, "pair.json")):
            sh([sys.executable, os.path.join(HERE, "kitti360_cross_pass.py"), k3, d,
                "--query", q, "--map", m, "--bin", bin_, "--via", cross_via]
               + (["--ground"] if cross_ground else []), check=True)
        # Both ways truth.json (the --init, and the reference the errors are taken against) is
        # in the map's own frame: KITTI-360's world frame (LOCAL) for --points, the tile's CRS
        # (the world frame + kitti360_cross_pass.py's --offset) for --tiles.
        source = (["--tiles", os.path.join(d, "tiles"), "--radius", str(CROSS_TILES_RADIUS_M)]
                  if cross_via == "tiles" else ["--points", os.path.join(d, "map.csv")])
        sets[f"cross-{q}-in-{m}{suffix}"] = (
            ["--camera", os.path.join(d, "camera.yaml"),
             "--image", os.path.join(k3, "image_00", f"{q:010d}.png")] + source
            + ["--init", os.path.join(d, "truth.json")], TOL_M_KITTI360)
    return sets


def run_set(bin_, name, args, out, extra=()):
    """One `refine --starts 3` run, its outputs in OUT/runs/NAME (skipped when done)."""
    d = os.path.join(out, "runs", name)
    done = os.path.join(d, "run.json")
    if os.path.exists(done):
        return json.load(open(done))
    os.makedirs(d, exist_ok=True)
    report, pose = os.path.join(d, "report.json"), os.path.join(d, "pose.json")
    for p in (report, pose):
        if os.path.exists(p):
            os.remove(p)
    cmd = ([bin_, "refine"] + args + ["--starts", str(STARTS)] + list(extra)
           + ["--report", report, "--out", pose])
    t0 = time.monotonic()
    with open(os.path.join(d, "stdout"), "w") as so, open(os.path.join(d, "stderr"), "w") as se:
        rc = sh(cmd, stdout=so, stderr=se).returncode
    wall = time.monotonic() - t0
    err = open(os.path.join(d, "stderr")).read().strip().splitlines()
    rec = {"set": name, "command": [str(c) for c in cmd], "exit": rc, "wall_s": round(wall, 1),
           "stderr_last": err[-1] if err else ""}
    tmp = done + ".tmp"
    json.dump(rec, open(tmp, "w"), indent=2)
    os.replace(tmp, done)
    return rec


def grade_of(d):
    """The verdict of a quality/start record: `grade` when present (a string, or an object with
    a grade/name), else `accepted` → precise / refused."""
    g = d.get("grade")
    if isinstance(g, dict):
        g = g.get("grade") or g.get("name") or g.get("kind")
    if isinstance(g, str):
        return g.lower()
    if "accepted" in d:
        return "precise" if d["accepted"] else "refused"
    return "unknown"


def reason_of(d):
    for k in ("reason", "refusal", "why"):
        v = d.get(k)
        if v:
            return v if isinstance(v, str) else json.dumps(v)
    return ""


def sigma_of(d):
    s = d.get("sigma")
    if not isinstance(s, dict):
        return None
    return {a: (float(s[a]) if isinstance(s.get(a), (int, float)) else None) for a in AXES if a in s}


def within(err, sig, tol_m):
    """|error| ≤ 3σ + tolerance on every axis with a finite σ; None without a σ."""
    if not sig:
        return None, []
    out = []
    for i, a in enumerate(AXES):
        s = sig.get(a)
        if a not in sig:
            continue
        tol = tol_m if i < 3 else TOL_DEG
        if s is None or not math.isfinite(s) or abs(err[i]) > 3 * s + tol:
            out.append(a)
    return not out, out


def agree(served):
    """Served starts pairwise within their combined 3σ on every axis both have a σ for."""
    bad = []
    for i in range(len(served)):
        for j in range(i + 1, len(served)):
            a, b = served[i], served[j]
            for k, ax in enumerate(AXES):
                sa, sb = (a["sigma"] or {}).get(ax), (b["sigma"] or {}).get(ax)
                if sa is None or sb is None:
                    continue
                d = abs(a["error"][k] - b["error"][k])
                if d > 3 * math.hypot(sa, sb):
                    bad.append(f"starts {a['start']} and {b['start']}: {ax} {d:.3f}")
    return not bad, bad


def pose_error(cal, ans):
    """x, y, z (m) of the answer's camera centre minus the calibration's, the rotation between
    them about the map's up axis (deg, from the relative rotation's vector) and in all (deg)."""
    def centre_rot(p):
        r = np.array(p["rotation_cam_from_map"], float)
        return -r.T @ np.array(p["translation_cam_from_map"], float), r.T
    (c0, m0), (c1, m1) = centre_rot(cal), centre_rot(ans)
    rel = m1 @ m0.T
    angle = math.acos(max(-1.0, min(1.0, (np.trace(rel) - 1) / 2)))
    axis = np.array([rel[2, 1] - rel[1, 2], rel[0, 2] - rel[2, 0], rel[1, 0] - rel[0, 1]])
    n = np.linalg.norm(axis)
    vec = axis / n * angle if n > 0 else np.zeros(3)
    d = c1 - c0
    return {"x": float(d[0]), "y": float(d[1]), "z": float(d[2]),
            "horizontal": float(math.hypot(d[0], d[1])),
            "yaw_deg": float(math.degrees(vec[2])), "angle_deg": float(math.degrees(angle))}


def analyse(rec, tol_m):
    """Per-start rows and the set's verdict from the run's report."""
    d = os.path.dirname(rec["command"][rec["command"].index("--report") + 1])
    rp = os.path.join(d, "report.json")
    res = dict(rec, tolerance_m=tol_m, starts=[])
    if not os.path.exists(rp):
        res["outcome"] = "error"
        return res
    rep = json.load(open(rp))
    q = rep.get("quality", {})
    res["grade"] = grade_of(q)
    res["reason"] = reason_of(q)
    res["sigma"] = sigma_of(q)
    sc = rep.get("self_check") or {}
    res["self_check"] = {k: sc.get(k) for k in ("accepted", "agree", "disagreement", "answer")}
    starts = sc.get("starts") or []
    if not starts and "offsets" in rep:
        # No self-check in the report (a format this script does not know): the answer alone,
        # its offsets from the start that produced it (the calibration when that is start 1).
        starts = [dict(q, start=[0.0] * 6, offsets=rep["offsets"])]
        res["note"] = "no self_check.starts in the report: one row from its offsets"
    for n, s in enumerate(starts, 1):
        err = [float(v) for v in s["offsets"]]
        sig = sigma_of(s)
        ok, axes_out = within(err, sig, tol_m)
        res["starts"].append({
            "start": n, "start_offset": s["start"], "grade": grade_of(s), "reason": reason_of(s),
            "sigma": sig, "error": err, "horizontal_m": math.hypot(err[0], err[1]),
            "mi": s.get("mi"), "within": ok, "outside_on": axes_out,
            "answer": n - 1 == (sc.get("answer") or 0)})
    # The pose file (written when served), checked against the calibration without the tool's
    # chart: centre difference and the relative rotation's angle about the map's up axis.
    pf = os.path.join(d, "pose.json")
    init = rec["command"][rec["command"].index("--init") + 1]
    if os.path.exists(pf):
        res["pose_file_error"] = pose_error(json.load(open(init)), json.load(open(pf)))
    served = [s for s in res["starts"] if s["grade"] in ("precise", "coarse")]
    res["served_agree"], res["served_disagree"] = agree(served)
    res["outcome"] = "ran"
    return res


def short_reason(text):
    """The refusal's first clause, and how many optima it names (the report keeps it whole)."""
    if not text:
        return ""
    head = text.split(" (", 1)[0].split(";", 1)[0]
    m = re.search(r"(\d+) optim\w* the MI cannot tell", text)
    se = [float(v) for v in re.findall(r"ΔMI (-?[\d.]+) se", text)]
    if m:
        head += f"; {m.group(1)} optima within {max(se):.1f} se" if se else f"; {m.group(1)} optima"
    return head.replace("|", "/")


def fmt_sigma(s):
    if not s:
        return "–"
    cm = lambda a: "∞" if s.get(a) is None else f"{100 * s[a]:.1f}"
    yaw = "∞" if s.get("yaw") is None else f"{s['yaw']:.2f}"
    return f"{cm('x')}/{cm('y')}/{cm('z')} cm, {yaw}°"


def table(results):
    lines = ["| set | start | verdict | σ x/y/z, yaw | error x, y, z (cm), yaw (°) | horiz. (cm) | "
             "within 3σ+tol | why (refused) |", "|---|---|---|---|---|---|---|---|"]
    for r in results:
        if r["outcome"] == "error":
            lines.append(f"| {r['set']} | – | error (exit {r['exit']}) | – | – | – | – | "
                         f"{r['stderr_last'][:160]} |")
            continue
        for s in r["starts"]:
            e = s["error"]
            w = "–" if s["within"] is None else ("yes" if s["within"] else "no (" + ", ".join(s["outside_on"]) + ")")
            why = short_reason(s["reason"]) if s["grade"] == "refused" else ""
            lines.append(
                f"| {r['set']} | {s['start']}{'*' if s.get('answer') else ''} | {s['grade']} | {fmt_sigma(s['sigma'])} | "
                f"{100 * e[0]:+.1f}, {100 * e[1]:+.1f}, {100 * e[2]:+.1f}, {e[3]:+.2f} | "
                f"{100 * s['horizontal_m']:.1f} | {w} | {why} |")
    return "\n".join(lines)


FAMILIES = [("gantry", "TUMTraf S110 south1, refl./int., 4-/6-DoF"), ("kitti-obj", "KITTI object, one frame each"),
            ("kitti360-pooled", "KITTI-360 ten frames pooled"), ("kitti360-", "KITTI-360 single frames"),
            ("cross-", "KITTI-360 camera in another pass's map")]


def family_table(results):
    """One row per family of sets: runs, grades, served within, horizontal error and yaw range."""
    lines = ["| sets | runs | precise / coarse / refused | served within 3σ + tol | "
             "horiz. error median (range), cm | |yaw| error range, ° |", "|---|---|---|---|---|---|"]
    taken = set()
    for key, label in FAMILIES:
        rs = [r for r in results if r["set"].startswith(key) and r["set"] not in taken
              and not (key == "kitti360-" and r["set"] == "kitti360-pooled")]
        taken.update(r["set"] for r in rs)
        st = [s for r in rs for s in r["starts"]]
        if not rs:
            continue
        g = lambda x: sum(s["grade"] == x for s in st)
        served = [s for s in st if s["grade"] in ("precise", "coarse")]
        hz = sorted(100 * s["horizontal_m"] for s in st)
        yw = sorted(abs(s["error"][3]) for s in st)
        err = sum(r["outcome"] == "error" for r in rs)
        lines.append(
            f"| {label} ({len(rs)} sets{f', {err} errored' if err else ''}) | {len(st)} | "
            f"{g('precise')} / {g('coarse')} / {g('refused')} | "
            f"{sum(s['within'] is True for s in served)} of {len(served)} | "
            + (f"{hz[len(hz) // 2]:.0f} ({hz[0]:.0f}–{hz[-1]:.0f}) | {yw[0]:.2f}–{yw[-1]:.2f} |" if st else "– | – |"))
    return "\n".join(lines)


def summary(results):
    starts = [s for r in results for s in r["starts"]]
    served = [s for s in starts if s["grade"] in ("precise", "coarse")]
    by = lambda g: sum(s["grade"] == g for s in starts)
    outside = [s for s in served if s["within"] is not True]
    disagree = [r["set"] for r in results if r["outcome"] == "ran" and not r["served_agree"]]
    tool_disagree = [r["set"] for r in results if r["outcome"] == "ran"
                     and r["self_check"].get("agree") is False]
    with_sigma = [s for s in starts if s["within"] is not None]
    hz = sorted(s["horizontal_m"] for s in starts)
    return {
        "sets": len(results),
        "errors": [r["set"] for r in results if r["outcome"] == "error"],
        "runs": len(starts),
        "precise": by("precise"),
        "coarse": by("coarse"),
        "refused": by("refused"),
        "other": len(starts) - by("precise") - by("coarse") - by("refused"),
        "served": len(served),
        "served_at_least_half": 2 * len(served) >= len(starts) > 0,
        "served_outside_3sigma_plus_tol": len(outside),
        "sets_whose_served_starts_disagree": disagree,
        "sets_the_tool_self_check_calls_disagreeing": tool_disagree,
        "answers_with_sigma": len(with_sigma),
        "answers_with_sigma_within": sum(bool(s["within"]) for s in with_sigma),
        "horizontal_error_median_m": hz[len(hz) // 2] if hz else None,
        "horizontal_error_max_m": hz[-1] if hz else None,
        "wall_s": round(sum(r["wall_s"] for r in results), 1),
    }


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("bin", nargs="?", default="target/release/infraloc")
    ap.add_argument("out", nargs="?", default="/tmp/real-views")
    ap.add_argument("--data", default=os.path.join(HERE, "..", "..", "..", "shared", "data", "real"))
    ap.add_argument("--only", nargs="*", help="run only sets whose name contains one of these")
    ap.add_argument("--cross-via", choices=["points", "tiles"], default="points",
                    help="the cross-pass maps as --points CSV (default) or as a tile of the map "
                         "scan by `tile scans`, for refine --tiles (sets cross-Q-in-M-tiles)")
    ap.add_argument("--cross-ground", action="store_true",
                    help="the cross-pass maps from the scan's ground band only (a comparison; the "
                         "default keeps every point, as `refine --points FILE.bin` does)")
    ap.add_argument("--extra", default="", help="more refine flags for every run, e.g. "
                    "\"--search x=0.4:0.02,y=0.4:0.02,z=0.4:0.02,yaw=2.5:0.05\" (not the default "
                    "settings: use another OUT)")
    ap.add_argument("--json", help="where to write the runs and summary (default OUT/real_views.json)")
    ap.add_argument("--summary-only", action="store_true", help="tabulate the runs already made")
    a = ap.parse_args()
    if a.cross_ground and a.cross_via == "tiles":
        sys.exit("--cross-ground is for --cross-via points: a tile keeps the ground its own filter finds")
    bin_ = os.path.abspath(a.bin)
    out = os.path.abspath(a.out)
    data = os.path.abspath(a.data)
    if not os.access(bin_, os.X_OK):
        sys.exit(f"{bin_}: no such executable")
    os.makedirs(out, exist_ok=True)
    try:
        sets = prepare(bin_, data, os.path.join(out, "inputs"), a.cross_via, a.cross_ground)
    except subprocess.CalledProcessError as e:
        sys.exit(f"making the inputs failed (exit {e.returncode}): {' '.join(map(str, e.cmd))}")
    names = [n for n in sets if not a.only or any(s in n for s in a.only)]
    results = []
    for n in names:
        args, tol = sets[n]
        if a.summary_only and not os.path.exists(os.path.join(out, "runs", n, "run.json")):
            continue
        rec = run_set(bin_, n, args, out, shlex.split(a.extra))
        r = analyse(rec, tol)
        results.append(r)
        last = r["starts"]
        print(f"{n}: {r['outcome']}, {', '.join(s['grade'] for s in last) or r['stderr_last']}, "
              f"{rec['wall_s']} s", flush=True)
    summ = summary(results)
    cross = {}
    for n in names:
        p = os.path.join(out, "inputs", n, "pair.json")
        if n.startswith("cross-") and os.path.exists(p):
            cross[n] = json.load(open(p))
    doc = {"binary": bin_, "data": data, "starts": STARTS, "runs": results, "summary": summ,
           "cross_pass_inputs": cross}
    jpath = os.path.abspath(a.json or os.path.join(out, "real_views.json"))
    with open(jpath, "w") as f:
        json.dump(doc, f, indent=2)
    print()
    print(table(results))
    print("(* the start whose answer the tool gives: the served one of the highest MI, else start 1)")
    for r in results:
        pe, ans = r.get("pose_file_error"), [s for s in r["starts"] if s.get("answer")]
        if pe and ans:
            e = ans[0]["error"]
            gap = max(abs(pe[k] - e[i]) for i, k in enumerate("xyz"))
            if gap > 1e-3 or abs(pe["yaw_deg"] - e[3]) > 0.05:
                print(f"note: {r['set']}: the pose file's error ({pe['x']:+.3f}, {pe['y']:+.3f}, "
                      f"{pe['z']:+.3f}) m, yaw {pe['yaw_deg']:+.3f}° differs from the report's "
                      f"answer row")
    print()
    print(family_table(results))
    print()
    print(f"{summ['runs']} runs ({summ['sets']} sets × {STARTS} starts): {summ['precise']} precise, "
          f"{summ['coarse']} coarse, {summ['refused']} refused"
          + (f", {summ['other']} other" if summ["other"] else "")
          + (f"; sets that errored: {', '.join(summ['errors'])}" if summ["errors"] else ""))
    print(f"served {summ['served']} of {summ['runs']} (at least half: "
          f"{'yes' if summ['served_at_least_half'] else 'no'}); served outside 3σ + tolerance: "
          f"{summ['served_outside_3sigma_plus_tol']}; sets whose served starts disagree: "
          f"{', '.join(summ['sets_whose_served_starts_disagree']) or 'none'} (tool's self-check: "
          f"{', '.join(summ['sets_the_tool_self_check_calls_disagreeing']) or 'none'})")
    print(f"answers with a σ: {summ['answers_with_sigma']}, within 3σ + tolerance: "
          f"{summ['answers_with_sigma_within']}; horizontal error median "
          f"{100 * (summ['horizontal_error_median_m'] or 0):.1f} cm, max "
          f"{100 * (summ['horizontal_error_max_m'] or 0):.1f} cm; refine wall time {summ['wall_s']} s")
    print(f"wrote {jpath}")


if __name__ == "__main__":
    main()
