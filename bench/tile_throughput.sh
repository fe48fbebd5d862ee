#!/usr/bin/env bash
# Localization tile throughput: polmap's HTTP server vs nginx serving the same tile
# payloads as static files, both on loopback, measured with wrk in the same run.
#   bench/tile_throughput.sh [--side N] [--connections C] [--duration S] [--threads T]
#                            [--rounds R] [--log]
# Needs the Debian packages nginx and wrk (installed here if missing; they are not
# build dependencies, so tools/setup does not list them). Builds bench_tile_server into
# ${POLMAP_BUILD_DIR:-build}. Prints requests/s and p50/p99 latency per server and
# polmap's share of nginx's requests/s.
set -euo pipefail
cd "$(dirname "$0")/.."
SIDE=20 CONNS=32 DURATION=10 THREADS=32 ROUNDS=2 LOG=0
while [ $# -gt 0 ]; do
  case "$1" in
    --side) SIDE=$2; shift 2 ;;
    --connections) CONNS=$2; shift 2 ;;
    --duration) DURATION=$2; shift 2 ;;
    --threads) THREADS=$2; shift 2 ;;
    --rounds) ROUNDS=$2; shift 2 ;;
    --log) LOG=1; shift ;;
    *) echo "tile_throughput.sh: unknown argument '$1'" >&2; exit 2 ;;
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
NGINX=$(command -v nginx || echo /usr/sbin/nginx)

BUILD=${POLMAP_BUILD_DIR:-build}
if ! POLMAP_JOBS=${POLMAP_JOBS:-2} tools/build --target bench_tile_server >/dev/null 2>&1; then
  [ -x "$BUILD/bench/bench_tile_server" ] || { echo "cannot build bench_tile_server" >&2; exit 1; }
  echo "warning: build failed, using the existing $BUILD/bench/bench_tile_server" >&2
fi
WORK=$(mktemp -d /tmp/polmap-tile-bench.XXXXXX)
SERVER_PID="" NGINX_PID=""
cleanup() {
  [ -n "$SERVER_PID" ] && kill "$SERVER_PID" 2>/dev/null && wait "$SERVER_PID" 2>/dev/null || true
  [ -n "$NGINX_PID" ] && kill "$NGINX_PID" 2>/dev/null || true
  rm -rf "$WORK"
}
trap cleanup EXIT

# 1. polmap server with a synthetic map (the fixture also writes the static copy).
LOGARG=()
[ "$LOG" = 1 ] && LOGARG=(--log "$WORK/polmap-access.log")
"$BUILD/bench/bench_tile_server" --out "$WORK/data" --side "$SIDE" --threads "$THREADS" \
  "${LOGARG[@]}" > "$WORK/ready" 2> "$WORK/server.err" &
SERVER_PID=$!
for _ in $(seq 600); do grep -q READY "$WORK/ready" 2>/dev/null && break; sleep 0.1; done
grep -q READY "$WORK/ready" || { cat "$WORK/server.err"; echo "server did not start" >&2; exit 1; }
PM_PORT=$(awk '/READY/ {print $2}' "$WORK/ready")

chmod -R a+rX "$WORK"  # nginx workers run as an unprivileged user

# 2. nginx on the same files (same URL paths), as tuned as a static tile host would be.
NG_PORT=$((PM_PORT + 1))
while (exec 3<>/dev/tcp/127.0.0.1/$NG_PORT) 2>/dev/null; do NG_PORT=$((NG_PORT + 1)); done
ACCESS_LOG=off
[ "$LOG" = 1 ] && ACCESS_LOG="$WORK/nginx-access.log"
mkdir -p "$WORK/nginx"
cat > "$WORK/nginx/nginx.conf" <<EOF
worker_processes auto;
pid $WORK/nginx/nginx.pid;
error_log $WORK/nginx/error.log warn;
daemon off;
events { worker_connections 1024; }
http {
  access_log $ACCESS_LOG;
  sendfile on; tcp_nopush on; tcp_nodelay on;
  keepalive_requests 1000; keepalive_timeout 5s;
  open_file_cache max=10000 inactive=60s;
  default_type application/vnd.polmap.tile;
  client_body_temp_path $WORK/nginx/body; proxy_temp_path $WORK/nginx/proxy;
  fastcgi_temp_path $WORK/nginx/fcgi; uwsgi_temp_path $WORK/nginx/uwsgi; scgi_temp_path $WORK/nginx/scgi;
  server {
    listen 127.0.0.1:$NG_PORT;
    root $WORK/data/static;
    location /v1/tiles/ { add_header Cache-Control "public, max-age=60, must-revalidate"; }
  }
}
EOF
"$NGINX" -e "$WORK/nginx/error.log" -c "$WORK/nginx/nginx.conf" -p "$WORK/nginx" &
NGINX_PID=$!
for _ in $(seq 100); do curl -sf "http://127.0.0.1:$NG_PORT$(head -n1 "$WORK/data/paths.txt")" -o /dev/null && break; sleep 0.1; done

# 3. Both serve byte-identical tiles.
P=$(sed -n 7p "$WORK/data/paths.txt")
cmp <(curl -sf "http://127.0.0.1:$PM_PORT$P") <(curl -sf "http://127.0.0.1:$NG_PORT$P") \
  || { echo "payloads differ" >&2; exit 1; }

cat > "$WORK/random_tiles.lua" <<EOF
local paths = {}
for line in io.lines("$WORK/data/paths.txt") do paths[#paths + 1] = line end
math.randomseed(os.time())
request = function()
  return wrk.format("GET", paths[math.random(#paths)])
end
EOF

run_wrk() {  # name port -> "rps p50_ms p99_ms"
  local out
  out=$(wrk -t2 -c"$CONNS" -d"${DURATION}s" --latency -s "$WORK/random_tiles.lua" \
    "http://127.0.0.1:$2" 2>&1)
  echo "$out" > "$WORK/wrk-$1.txt"
  local rps p50 p99 errs
  rps=$(echo "$out" | awk '/Requests\/sec/ {print $2}')
  p50=$(echo "$out" | awk '$1 == "50%" {print $2}')
  p99=$(echo "$out" | awk '$1 == "99%" {print $2}')
  errs=$(echo "$out" | awk '/Non-2xx|Socket errors/ {print}' | tr '\n' ' ')
  echo "$rps $p50 $p99 ${errs:-}"
}

echo "tiles: $((SIDE * SIDE)) z16 tiles, $(du -sb "$WORK/data/static" | cut -f1) bytes; wrk -t2 -c$CONNS -d${DURATION}s, random tiles; $(nproc) cores"
printf "%-6s %-8s %12s %10s %10s  %s\n" round server "requests/s" "p50" "p99" notes
for round in $(seq "$ROUNDS"); do
  read -r PM_RPS PM_P50 PM_P99 PM_NOTE <<< "$(run_wrk polmap "$PM_PORT")"
  printf "%-6s %-8s %12s %10s %10s  %s\n" "$round" polmap "$PM_RPS" "$PM_P50" "$PM_P99" "${PM_NOTE:-}"
  read -r NG_RPS NG_P50 NG_P99 NG_NOTE <<< "$(run_wrk nginx "$NG_PORT")"
  printf "%-6s %-8s %12s %10s %10s  %s\n" "$round" nginx "$NG_RPS" "$NG_P50" "$NG_P99" "${NG_NOTE:-}"
  awk -v a="$PM_RPS" -v b="$NG_RPS" 'BEGIN { printf "       polmap / nginx = %.0f %%\n", 100 * a / b }'
done
