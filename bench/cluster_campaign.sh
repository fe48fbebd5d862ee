#!/usr/bin/env bash
# Scale campaign of the PostgreSQL cluster (README "Scale-out figures"): a declared synthetic
# fleet (bench_fleet_packages: a street grid, landmarks-only packages) uploaded through nginx
# to two `polmap serve` replicas on one durable PostgreSQL 15 + PostGIS 3 cluster; then
#   - ingest rate through the two replicas (8 uploads at a time);
#   - store size per drive-km (database + package directory);
#   - partitioned build time with 1, 2 and 4 `polmap build-worker` processes;
#   - localization tile requests/s and p50/p99 with wrk, in the same run: through nginx to
#     the replicas, from the signed static publication (deploy/nginx/render-publication),
#     and from nginx serving the same tile files as plain static files;
#   - time from a publish through replica 1 until replica 2 serves the new version.
#   bench/cluster_campaign.sh [--drives N] [--grid G] [--workers "1 2 4"] [--duration S]
#                             [--connections C] [--out DIR]
# Needs wrk and nginx (installed here if missing). Defaults: 1,000 drives of 1 km on a
# 10 x 10 km grid (220 km of roads).
set -euo pipefail
cd "$(dirname "$0")/.."
DRIVES=1000 GRID=10 WORKERS="1 2 4" DURATION=10 CONNS=32 OUT=""
while [ $# -gt 0 ]; do
  case "$1" in
    --drives) DRIVES=$2; shift 2 ;;
    --grid) GRID=$2; shift 2 ;;
    --workers) WORKERS=$2; shift 2 ;;
    --duration) DURATION=$2; shift 2 ;;
    --connections) CONNS=$2; shift 2 ;;
    --out) OUT=$2; shift 2 ;;
    *) echo "cluster_campaign.sh: unknown argument '$1'" >&2; exit 2 ;;
  esac
done
missing=()
command -v wrk >/dev/null || missing+=(wrk)
command -v nginx >/dev/null || [ -x /usr/sbin/nginx ] || missing+=(nginx)
if [ ${#missing[@]} -gt 0 ]; then
  SUDO=""; [ "$(id -u)" -eq 0 ] || SUDO="sudo"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
fi
BUILD=${POLMAP_BUILD_DIR:-build}
POLMAP_JOBS=${POLMAP_JOBS:-2} tools/build --target polmap bench_fleet_packages >/dev/null
POLMAP=$BUILD/tools/polmap
[ -n "$OUT" ] || OUT=$(mktemp -d /tmp/polmap-campaign-XXXXXX)
mkdir -p "$OUT"; OUT=$(cd "$OUT" && pwd); chmod 755 "$OUT"
rm -rf "$OUT"/{pkg,pg,packages,nginx*,pub,logs}; mkdir -p "$OUT/logs"
PIDS=() WORKER_PIDS=()
stop_workers() {
  for p in "${WORKER_PIDS[@]}"; do kill "$p" 2>/dev/null || true; done
  for p in "${WORKER_PIDS[@]}"; do wait "$p" 2>/dev/null || true; done
  WORKER_PIDS=()
}
cleanup() {
  stop_workers
  for p in "${PIDS[@]}"; do kill "$p" 2>/dev/null || true; done
  wait 2>/dev/null || true
  for n in nginx nginx-pub nginx-static; do
    [ -f "$OUT/$n/nginx.pid" ] && nginx -p "$OUT/$n" -c "$OUT/$n/nginx.conf" \
      -e "$OUT/$n/logs/error.log" -s quit 2>/dev/null || true
  done
  tools/postgres stop "$OUT/pg" >/dev/null 2>&1 || true
}
trap cleanup EXIT
free_port() {
  local p
  while :; do
    p=$((20000 + RANDOM % 12000))
    (exec 3<>/dev/tcp/127.0.0.1/$p) 2>/dev/null || { echo "$p"; return; }
  done
}
now() { date +%s.%N; }
wait_health() {
  for _ in $(seq 400); do curl -sf "$1/health" >/dev/null 2>&1 && return 0; sleep 0.05; done
  echo "cluster_campaign.sh: $1 did not come up" >&2; exit 1
}
echo "machine: $(nproc) cores, $(awk '/MemTotal/ {printf "%.0f GiB", $2 / 1048576}' /proc/meminfo); $(date -u +%Y-%m-%dT%H:%MZ)"

echo "== fleet: $DRIVES drives"
FLEET=$("$BUILD/bench/bench_fleet_packages" --out "$OUT/pkg" --drives "$DRIVES" --grid "$GRID")
echo "   $FLEET"
DRIVE_KM=$(echo "$FLEET" | awk '{print $4}')

echo "== cluster: durable PostgreSQL, two replicas behind nginx"
DB=$(tools/postgres start "$OUT/pg" | tail -n 1)
KEY=$(head -c 16 /dev/urandom | od -An -tx1 | tr -d ' \n')
echo "operator $KEY" > "$OUT/api-keys"
UP=() REPLICA=()
for i in 1 2; do
  port=$(free_port)
  "$POLMAP" serve --db "$DB" --package-dir "$OUT/packages" --listen "127.0.0.1:$port" \
    --api-key-file "$OUT/api-keys" --build-partition-zoom 14 --no-build-jobs --quiet \
    --max-concurrent-uploads 16 > "$OUT/logs/replica-$i.log" 2>&1 &
  PIDS+=($!)
  wait_health "http://127.0.0.1:$port"
  UP+=(--upstream "127.0.0.1:$port")
  REPLICA+=("http://127.0.0.1:$port")
done
NGINX_PORT=$(free_port)
# Per-client limits off: wrk is one client on loopback (the shipped defaults would answer
# most of its requests 503, which is their job in service).
deploy/nginx/render --prefix "$OUT/nginx" --listen "127.0.0.1:$NGINX_PORT" "${UP[@]}" \
  --conn-per-ip 60000 --rate-per-ip 1000000 --burst-per-ip 1000000 >/dev/null 2>&1
nginx -p "$OUT/nginx" -c "$OUT/nginx/nginx.conf" -e "$OUT/nginx/logs/error.log"
URL="http://127.0.0.1:$NGINX_PORT"
wait_health "$URL"

db_empty=$(psql "$DB" -Atc "SELECT pg_database_size(current_database())")
echo "== ingest through nginx (8 uploads at a time)"
t0=$(now)
ls "$OUT"/pkg/*.tar | xargs -P 8 -n 1 "$POLMAP" upload --server "$URL" --api-key "$KEY" \
  --package > "$OUT/logs/uploads.log" 2>&1
t1=$(now)
stored=$(psql "$DB" -Atc "SELECT count(*) FROM drives")
[ "$stored" = "$DRIVES" ] || { echo "cluster_campaign.sh: $stored of $DRIVES drives stored" >&2; exit 1; }
awk -v n="$DRIVES" -v km="$DRIVE_KM" -v a="$t0" -v b="$t1" \
  'BEGIN { printf "   %d drives in %.1f s: %.1f drives/s, %.1f drive-km/s\n", n, b - a, n / (b - a), km / (b - a) }'
db_bytes=$(psql "$DB" -Atc "SELECT pg_database_size(current_database())")
pkg_bytes=$(du -sb "$OUT/packages" | cut -f1)
awk -v d="$db_bytes" -v e="$db_empty" -v p="$pkg_bytes" -v km="$DRIVE_KM" \
  'BEGIN { printf "   store: database %.1f MB (%.1f MB of it before the first drive) + packages %.1f MB: %.1f kB per drive-km\n", d / 1e6, e / 1e6, p / 1e6, (d - e + p) / 1e3 / km }'

echo "== partitioned builds (zoom 14 regions), $(nproc) cores"
for w in $WORKERS; do
  for i in $(seq "$w"); do
    "$POLMAP" build-worker --db "$DB" --id "w$w-$i" --idle-poll-s 0.05 \
      > "$OUT/logs/worker-$w-$i.log" 2>&1 &
    WORKER_PIDS+=($!)
  done
  t0=$(now)
  V=$("$POLMAP" build-map --server "$URL" --api-key "$KEY" --wait)
  t1=$(now)
  stop_workers
  jobs=$(psql "$DB" -Atc "SELECT count(*) FROM build_jobs WHERE version = $V AND kind = 'region'")
  lms=$(psql "$DB" -Atc "SELECT (statistics_json->>'point_landmarks')::int + (statistics_json->>'line_landmarks')::int FROM map_versions WHERE version = $V")
  awk -v w="$w" -v a="$t0" -v b="$t1" -v j="$jobs" -v l="$lms" -v v="$V" \
    'BEGIN { printf "   %d worker(s): version %d, %d region jobs, %d landmarks, %.1f s\n", w, v, j, l, b - a }'
done
sleep 1  # replicas re-read the current version every 0.5 s

echo "== tiles: through nginx to the replicas, static publication, plain nginx static"
"$POLMAP" keygen --out "$OUT/pubkey" >/dev/null
"$POLMAP" publish --db "$DB" --out "$OUT/pub" --key "$OUT/pubkey.key" --no-gridmap > "$OUT/logs/publish.log"
PUBDIR=$(ls -d "$OUT"/pub/v*/ | head -n 1); PUBDIR=${PUBDIR%/}
(cd "$PUBDIR" && find loc -name '*.pmt' | sort) > "$OUT/loc-files.txt"
sed -E 's|^loc/([0-9]+)/([0-9]+)/([0-9]+)\.pmt$|/v1/tiles/\1/\2/\3|' "$OUT/loc-files.txt" > "$OUT/paths-replicas.txt"
sed -E "s|^|/$(basename "$PUBDIR")/|" "$OUT/loc-files.txt" > "$OUT/paths-static.txt"
chmod -R a+rX "$OUT/pub"
PUB_PORT=$(free_port)
deploy/nginx/render-publication --prefix "$OUT/nginx-pub" --listen "127.0.0.1:$PUB_PORT" --root "$OUT/pub" >/dev/null 2>&1
nginx -p "$OUT/nginx-pub" -c "$OUT/nginx-pub/nginx.conf" -e "$OUT/nginx-pub/logs/error.log"
ST_PORT=$(free_port)
mkdir -p "$OUT/nginx-static/logs"
cat > "$OUT/nginx-static/nginx.conf" <<EOF
worker_processes auto;
pid $OUT/nginx-static/nginx.pid;
events { worker_connections 1024; }
http {
  access_log off;
  sendfile on; tcp_nopush on; tcp_nodelay on;
  keepalive_requests 1000; keepalive_timeout 5s;
  open_file_cache max=10000 inactive=60s;
  default_type application/octet-stream;
  client_body_temp_path $OUT/nginx-static/body; proxy_temp_path $OUT/nginx-static/proxy;
  fastcgi_temp_path $OUT/nginx-static/fcgi; uwsgi_temp_path $OUT/nginx-static/uwsgi; scgi_temp_path $OUT/nginx-static/scgi;
  server { listen 127.0.0.1:$ST_PORT; root $OUT/pub; }
}
EOF
nginx -p "$OUT/nginx-static" -c "$OUT/nginx-static/nginx.conf" -e "$OUT/nginx-static/logs/error.log"
sleep 0.5
P1=$(head -n 1 "$OUT/paths-replicas.txt") P2=$(head -n 1 "$OUT/paths-static.txt")
cmp <(curl -sf "$URL$P1") <(curl -sf "http://127.0.0.1:$PUB_PORT$P2") ||
  { echo "cluster_campaign.sh: replica and publication tiles differ" >&2; exit 1; }
run_wrk() {  # name port paths-file -> "rps p50 p99 notes"
  cat > "$OUT/wrk-$1.lua" <<EOF
local paths = {}
for line in io.lines("$3") do paths[#paths + 1] = line end
math.randomseed(os.time())
request = function() return wrk.format("GET", paths[math.random(#paths)]) end
EOF
  local out rps p50 p99 errs
  out=$(wrk -t2 -c"$CONNS" -d"${DURATION}s" --latency -s "$OUT/wrk-$1.lua" "http://127.0.0.1:$2" 2>&1)
  echo "$out" > "$OUT/wrk-$1.txt"
  rps=$(echo "$out" | awk '/Requests\/sec/ {print $2}')
  p50=$(echo "$out" | awk '$1 == "50%" {print $2}')
  p99=$(echo "$out" | awk '$1 == "99%" {print $2}')
  errs=$(echo "$out" | awk '/Non-2xx|Socket errors/ {print}' | tr '\n' ' ')
  echo "$rps $p50 $p99 ${errs:-}"
}
echo "   $(wc -l < "$OUT/paths-replicas.txt") localization tiles; wrk -t2 -c$CONNS -d${DURATION}s, random tiles"
printf "   %-32s %12s %10s %10s  %s\n" server "requests/s" p50 p99 notes
for name in replicas publication static; do
  case $name in
    replicas) port=$NGINX_PORT paths=$OUT/paths-replicas.txt label="nginx -> 2 replicas" ;;
    publication) port=$PUB_PORT paths=$OUT/paths-static.txt label="static publication (nginx)" ;;
    static) port=$ST_PORT paths=$OUT/paths-static.txt label="plain nginx static files" ;;
  esac
  read -r rps p50 p99 note <<< "$(run_wrk "$name" "$port" "$paths")"
  printf "   %-32s %12s %10s %10s  %s\n" "$label" "$rps" "$p50" "$p99" "${note:-}"
done

echo "== publish on replica 1 -> served by replica 2"
for w in 1 2; do
  "$POLMAP" build-worker --db "$DB" --id "lat-$w" --idle-poll-s 0.05 > "$OUT/logs/worker-lat-$w.log" 2>&1 &
  WORKER_PIDS+=($!)
done
version_of() { curl -sI "$1$P1" | awk 'tolower($1) == "x-polmap-map-version:" {print $2}' | tr -d '\r'; }
for round in 1 2 3; do
  before=$(version_of "${REPLICA[1]}")
  V=$("$POLMAP" build-map --server "${REPLICA[0]}" --api-key "$KEY")
  t_pub="" t_serve=""
  for _ in $(seq 20000); do
    if [ -z "$t_pub" ] && [ "$(psql "$DB" -Atc "SELECT status FROM map_versions WHERE version = $V")" = published ]; then
      t_pub=$(now)
    fi
    if [ -n "$t_pub" ] && [ "$(version_of "${REPLICA[1]}")" = "$V" ]; then t_serve=$(now); break; fi
    sleep 0.01
  done
  [ -n "$t_serve" ] || { echo "cluster_campaign.sh: replica 2 never served version $V" >&2; exit 1; }
  awk -v r="$round" -v v="$V" -v b="$before" -v a="$t_pub" -v c="$t_serve" \
    'BEGIN { printf "   round %d: version %d (was %s) served by replica 2 %.0f ms after its publish\n", r, v, b, 1000 * (c - a) }'
done
stop_workers
echo "outputs in $OUT"
