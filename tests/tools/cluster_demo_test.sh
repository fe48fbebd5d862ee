#!/usr/bin/env bash
# tools/cluster-demo on a small route, with the crash drill: PostgreSQL, two replicas behind
# nginx, two build workers of which one is killed with SIGKILL holding a job; the script
# itself fails unless the build completes with the job claimed again, the version is whole
# and the held-out drive localizes through nginx. Here we also check the accuracy line.
set -euo pipefail
cd "$(dirname "$0")/../.."
out=$(mktemp -d /tmp/polmap-cluster-demo-XXXXXX)
chmod 755 "$out"  # PostgreSQL runs as its own user when we are root: it must reach pg/
trap 'rm -rf "$out"' EXIT
log="$out.log"
tools/cluster-demo --no-build --kill-worker --length-m 300 --drives 3 --out "$out/run" | tee "$log"
grep -q "worker-1 killed (SIGKILL) holding a job" "$log"
grep -q "job(s) claimed again after the kill" "$log"
lateral=$(grep -o 'lateral      RMSE [0-9.]*' "$log" | grep -o '[0-9.]*$')
awk -v l="$lateral" 'BEGIN { exit !(l > 0 && l < 0.2) }' ||
  { echo "cluster_demo_test: lateral RMSE $lateral m (expected < 0.2 m)" >&2; exit 1; }
rm -f "$log"
echo "cluster_demo_test: ok (lateral RMSE $lateral m)"
