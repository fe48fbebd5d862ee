#!/usr/bin/env python3
"""Compare `polmap study` results of two commits, route by route.

    bench/compare_studies.py BASE_DIR NEW_DIR   # each holds <route>.study.json

Prints per route: x real time (min–max over drives, CPU of every localizer thread),
p99 of the CPU per process() call (max over drives), pooled errors (RMSE of long, lat,
rot) and their change, converged/diverged drives, and the per-stage budget (ms of CPU
per second of driving, mean over drives) where NEW_DIR has it.
"""
import json
import pathlib
import sys


def load(d):
    return {p.name.removesuffix(".study.json"): json.loads(p.read_text())
            for p in sorted(pathlib.Path(d).glob("*.study.json"))}


def summary(s):
    res = s["results"]
    lvl = s["levels"][0]
    e = lvl["errors"]
    rt = [r["realtime_factor"] for r in res]
    p99 = [r.get("frame_p99_ms", float("nan")) for r in res]
    return {
        "rt": (min(rt), max(rt)), "p99": max(p99),
        "long": e["long_rmse_m"], "lat": e["lat_rmse_m"], "rot": e["rot_rmse_deg"],
        "conv": lvl["converged"], "div": lvl["diverged"], "n": lvl["drives"],
        "stages": [r["stage_ms_per_s"] for r in res if r.get("stage_ms_per_s")],
    }


def pct(new, old):
    return f"{100.0 * (new - old) / old:+.0f} %" if old else "n/a"


def main():
    base, new = load(sys.argv[1]), load(sys.argv[2])
    print("| route | x real time before → after | p99 ms/frame after | long RMSE [m] | lat RMSE [m]"
          " | rot RMSE [°] | converged / diverged |")
    print("|---|---|---|---|---|---|---|")
    for route in new:
        n = summary(new[route])
        b = summary(base[route]) if route in base else None
        if b:
            print(f"| {route} | {b['rt'][0]:.1f}–{b['rt'][1]:.1f} → **{n['rt'][0]:.1f}–{n['rt'][1]:.1f}** | "
                  f"{n['p99']:.0f} | {b['long']:.3f} → {n['long']:.3f} ({pct(n['long'], b['long'])}) | "
                  f"{b['lat']:.3f} → {n['lat']:.3f} ({pct(n['lat'], b['lat'])}) | "
                  f"{b['rot']:.2f} → {n['rot']:.2f} ({pct(n['rot'], b['rot'])}) | "
                  f"{b['conv']}/{b['div']} → {n['conv']}/{n['div']} of {n['n']} |")
        else:
            print(f"| {route} | → {n['rt'][0]:.1f}–{n['rt'][1]:.1f} | {n['p99']:.0f} | {n['long']:.3f} | "
                  f"{n['lat']:.3f} | {n['rot']:.2f} | {n['conv']}/{n['div']} of {n['n']} |")
    keys = ["egomotion", "gridmap", "points", "lines", "clustering", "tiles", "matching",
            "smoothing", "graph", "other", "total"]
    print()
    print("| route | " + " | ".join(keys) + " |")
    print("|---|" + "---|" * len(keys))
    for route in new:
        st = summary(new[route])["stages"]
        if not st:
            continue
        mean = {k: sum(s.get(k, 0.0) for s in st) / len(st) for k in keys}
        print(f"| {route} | " + " | ".join(f"{mean[k]:.1f}" for k in keys) + " |")


if __name__ == "__main__":
    main()
