#!/usr/bin/env bash
# The web console in a real browser (Debian's Chromium, driven by playwright-core from
# web/console's npm lock file): a small simulated map (3 drives of 300 m in a world made
# from a Lanelet2 HD map, two versions, so there is a diff; the HD-map comparison stored
# with version 2; the held-out drive's localization run reported), `polmap serve` on
# loopback, then tests/web/console_test.mjs. Screenshots
# go to ${POLMAP_TEST_ARTIFACTS:-build/test-artifacts}/console/.
set -euo pipefail
cd "$(dirname "$0")/../.."
POLMAP=${POLMAP_BIN:-build/tools/polmap}
ART=${POLMAP_TEST_ARTIFACTS:-$PWD/build/test-artifacts}/console
mkdir -p "$ART"
work=$(mktemp -d /tmp/polmap-console-test-XXXXXX)
SERVER_PID=""
cleanup() { [ -z "$SERVER_PID" ] || kill "$SERVER_PID" 2>/dev/null || true; rm -rf "$work"; }
trap cleanup EXIT
# A world made from a Lanelet2 HD map, so the stored HD-map comparison means something.
HDMAP=data/hdmaps/autoware_road_shoulder.osm
"$POLMAP" simulate --realism ideal --world "$HDMAP" --length-m 300 --drives 3 --seed 5 --out "$work/sim" >/dev/null
for i in 0 1 2; do
  "$POLMAP" process --recording "$work/sim/drive_$i.pmrec" --out "$work/pkg_$i" >/dev/null
done
KEY=$(head -c 16 /dev/urandom | od -An -tx1 | tr -d ' \n')
echo "operator $KEY" > "$work/keys"
"$POLMAP" serve --db "$work/map.sqlite" --listen 127.0.0.1:0 --api-key-file "$work/keys" \
  2> "$work/server.log" &
SERVER_PID=$!
PORT=""
for _ in $(seq 1 400); do
  PORT=$(grep -o 'listening on http://127.0.0.1:[0-9]*' "$work/server.log" | grep -o '[0-9]*$' || true)
  [ -n "$PORT" ] && curl -fsS -o /dev/null "http://127.0.0.1:$PORT/health" 2>/dev/null && break
  sleep 0.05
done
URL="http://127.0.0.1:$PORT"
for i in 0 1; do "$POLMAP" upload --server "$URL" --package "$work/pkg_$i" --api-key "$KEY" >/dev/null; done
"$POLMAP" build-map --server "$URL" --api-key "$KEY" --wait >/dev/null
# The held-out drive localizes against version 1 and reports its run (errors from the
# simulator's truth), as tools/demo does.
"$POLMAP" localize --server "$URL" --recording "$work/sim/drive_2.pmrec" --cache "$work/cache" \
  --out "$work/loc_2.csv" --report "$URL" --api-key "$KEY" \
  --truth "$work/sim/truth/drive_2_trajectory.csv" >/dev/null
"$POLMAP" upload --server "$URL" --package "$work/pkg_2" --api-key "$KEY" >/dev/null
"$POLMAP" build-map --server "$URL" --api-key "$KEY" --wait >/dev/null
# The HD-map overlay: the comparison stored with version 2 (the store is shared with the
# running server, as an export's would be).
"$POLMAP" compare-hdmap --db "$work/map.sqlite" --hdmap "$HDMAP" --store --name road_shoulder >/dev/null
POLMAP_URL="$URL" POLMAP_KEY="$KEY" POLMAP_SERVER_LOG="$work/server.log" POLMAP_ARTIFACTS="$ART" \
  NODE_PATH="$PWD/web/console/node_modules" node tests/web/console_test.mjs
