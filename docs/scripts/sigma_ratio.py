#!/usr/bin/env python3
"""σ against the truth from `pipeline_accuracy --json` files: per axis (x, y, z in m, yaw in °)
the 3σ coverage and the median of |error| / σ, over the accepted seeds; the accepted count and
the ground error (median / p95, cm) of the summary.

    python3 docs/scripts/sigma_ratio.py small.json [5mp.json …]
"""
import json
import sys

AXES = ["x", "y", "z", "yaw"]


def median(v):
    v = sorted(v)
    n = len(v)
    if n == 0:
        return float("nan")
    return v[n // 2] if n % 2 else 0.5 * (v[n // 2 - 1] + v[n // 2])


def main():
    for path in sys.argv[1:]:
        doc = json.load(open(path))
        recs = doc["seeds"] if isinstance(doc, dict) and "seeds" in doc else doc["records"]
        acc = [r for r in recs if "failure" not in r and r.get("mi_quality", {}).get("sigma")]
        cov, ratio = [], []
        for a in AXES:
            r = [abs(x["errors"]["mi"]["signed"][a]) / x["mi_quality"]["sigma"][a] for x in acc
                 if x["mi_quality"]["sigma"][a] > 0]
            cov.append(f"{a} {100 * sum(v <= 3 for v in r) / max(len(r), 1):.0f} %")
            ratio.append(f"{a} {median(r):.2f}")
        g = doc.get("summary", {}).get("ground", {}).get("mi", {}).get("all", {})
        ground = f"{100 * g.get('median', float('nan')):.2f} / {100 * g.get('p95', float('nan')):.2f} cm" if g else "?"
        print(f"{path}: accepted {len(acc)} of {len(recs)}; ground {ground}; 3σ coverage "
              f"{', '.join(cov)}; median |error|/σ {', '.join(ratio)}")


if __name__ == "__main__":
    main()
