#!/usr/bin/env bash
# Table IV under both simulator presets (issue 15): `polmap study` for each world with
# --realism ideal and --realism realistic, then one table with the accuracy (long, lat,
# rot RMSE), the uncertainty figures (mean NEES, share within chi2_3(0.95), lateral
# protection level's bounded share) and the run time, next to the paper's figures.
#   bench/realism_study.sh [--worlds "urban industrial rural data/hdmaps/X.osm"]
#                          [--length-m 600] [--drives 3] [--seeds 1] [--out DIR]
#                          [--table-only]
# --table-only prints the table of studies already in DIR (e.g. run one world at a time,
# or two at once on two cores: `polmap study ... --out DIR/<world>-<preset>`).
# Each study takes about 3 minutes on 2 cores (600 m, 3 drives, full polarimetry).
set -euo pipefail
cd "$(dirname "$0")/.."
WORLDS="urban industrial rural data/hdmaps/autoware_road_shoulder.osm" LENGTH=600 DRIVES=3
SEEDS=1 OUT=realism-study TABLE_ONLY=0
while [ $# -gt 0 ]; do
  case "$1" in
    --worlds) WORLDS=$2; shift 2 ;;
    --length-m) LENGTH=$2; shift 2 ;;
    --drives) DRIVES=$2; shift 2 ;;
    --seeds) SEEDS=$2; shift 2 ;;
    --out) OUT=$2; shift 2 ;;
    --table-only) TABLE_ONLY=1; shift ;;
    *) echo "realism_study.sh: unknown argument '$1'" >&2; exit 2 ;;
  esac
done
POLMAP=${POLMAP_BIN:-build/tools/polmap}
mkdir -p "$OUT"
for world in $WORLDS; do
  [ "$TABLE_ONLY" = 1 ] && break
  name=$(basename "$world" .osm)
  for realism in ideal realistic; do
    dir="$OUT/$name-$realism"
    echo "== $name, $realism"
    "$POLMAP" study --world "$world" --length-m "$LENGTH" --drives "$DRIVES" --seeds "$SEEDS" \
      --realism "$realism" --out "$dir" > "$dir.txt"
  done
done
python3 - "$OUT" $WORLDS <<'PY'
import json, os, sys
out = sys.argv[1]
print("| world | preset | long RMSE m | lat RMSE m | rot RMSE deg | lat max m | mean NEES | NEES <= q95 | PL bounds lat | mean PL m | conv | diverged | study s |")
print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
for world in sys.argv[2:]:
    name = os.path.basename(world).removesuffix(".osm")
    for realism in ("ideal", "realistic"):
        p = os.path.join(out, f"{name}-{realism}", "study.json")
        if not os.path.exists(p):
            continue
        j = json.load(open(p))
        lv = j["levels"][0]
        e = lv["errors"]
        print(f"| {name} | {realism} | {e['long_rmse_m']:.3f} | {e['lat_rmse_m']:.3f} | "
              f"{e['rot_rmse_deg']:.2f} | {e['lat_max_m']:.3f} | {e['nees_mean']:.2f} | {100*e['nees_within_q95_share']:.1f} % | "
              f"{100*e['pl_bounded_share']:.2f} % | {e['pl_mean_m']:.3f} | {lv['converged']}/{lv['drives']} | "
              f"{lv['diverged']}/{lv['drives']} | {j['wall_s']:.0f} |")
print("| paper (real drives) | | 0.08-0.15 | 0.05-0.06 | 0.37-0.48 | | | | | | | | |")
PY
