#!/usr/bin/env bash
# tools/postgres end to end: two throw-away clusters started at the same time get
# different ports, PostGIS works through the printed URL (a geometry(Point,4326) table with
# a GiST index, queried with ST_DWithin), status/stop/restart behave as documented, a
# long directory gets its socket under /tmp, and stopping leaves the port closed. Needs
# postgresql-15 and postgresql-15-postgis-3 (tools/setup); it fails, never skips, without
# them. Runs as root (the server then runs as polmap-pg) or as any user.
set -euo pipefail

ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
PG=$ROOT/tools/postgres
PSQL=/usr/lib/postgresql/15/bin/psql
start_s=$SECONDS
passed=0

dirs=()   # cluster directories, stopped and removed by cleanup
scratch=$(mktemp -d) # start's stdout and stderr
cleanup() {
  local rc=$?
  for d in ${dirs[@]+"${dirs[@]}"}; do
    if [ "$rc" -ne 0 ] && [ -s "$d/postgres.log" ]; then
      echo "--- last lines of $d/postgres.log" >&2
      tail -n 20 "$d/postgres.log" >&2 || true
    fi
    "$PG" stop "$d" >/dev/null 2>&1 || echo "cleanup: tools/postgres stop $d failed" >&2
    rm -rf -- "$d"
  done
  rm -rf -- "$scratch"
  if [ "$rc" -ne 0 ]; then echo "postgres_script_test: FAILED (exit $rc)" >&2; fi
}
trap cleanup EXIT
trap 'exit 130' INT # ctest's timeout sends TERM: clean up then too
trap 'exit 143' TERM

fail() {
  echo "postgres_script_test: FAIL: $*" >&2
  exit 1
}
ok() {
  passed=$((passed + 1))
  echo "ok $passed - $*"
}
new_dir() { # new_dir VAR TEMPLATE: a fresh directory for one cluster (mktemp -d) into VAR
  local d
  d=$(mktemp -d "$2") || fail "mktemp -d $2"
  dirs+=("$d")
  printf -v "$1" '%s' "$d"
}
port_of() { # the port of a postgresql://USER@127.0.0.1:PORT/DB URL
  [[ "$1" =~ ^postgresql://[a-z_][a-z0-9_-]*@127\.0\.0\.1:([0-9]+)/polmap$ ]] ||
    fail "'$1' is not a postgresql://USER@127.0.0.1:PORT/polmap URL"
  echo "${BASH_REMATCH[1]}"
}
port_open() { (exec 3<>"/dev/tcp/127.0.0.1/$1") 2>/dev/null; }
sql() { # psql on URL $1, the remaining arguments as psql's; one unaligned value per line
  local url=$1
  shift
  "$PSQL" -X -q -At -v ON_ERROR_STOP=1 "$url" "$@"
}
status_of() { # "OUTPUT|EXIT" of tools/postgres status
  local out rc=0
  out=$("$PG" status "$1" 2>&1) || rc=$?
  echo "$(echo "$out" | head -n 1)|$rc"
}

[ -x "$PG" ] || fail "$PG is not executable"
[ -x "$PSQL" ] || fail "$PSQL not found: install postgresql-15 (tools/setup)"

# --- two clusters started at the same time ----------------------------------------------------
dir_a="" dir_b="" long=""
new_dir dir_a "${TMPDIR:-/tmp}/polmap-pgtest.XXXXXX"
new_dir dir_b "${TMPDIR:-/tmp}/polmap-pgtest.XXXXXX"
# Started from another working directory, with DIR relative to it for A.
(cd "$(dirname "$dir_a")" && "$PG" start --fast "$(basename "$dir_a")" >"$scratch/a.out" 2>"$scratch/a.err") &
pid_a=$!
"$PG" start --fast "$dir_b" >"$scratch/b.out" 2>"$scratch/b.err" &
pid_b=$!
rc_a=0 rc_b=0
wait "$pid_a" || rc_a=$?
wait "$pid_b" || rc_b=$?
[ "$rc_a" -eq 0 ] || { cat "$scratch/a.err" >&2; fail "tools/postgres start $dir_a exited $rc_a"; }
[ "$rc_b" -eq 0 ] || { cat "$scratch/b.err" >&2; fail "tools/postgres start $dir_b exited $rc_b"; }
url_a=$(tail -n 1 "$scratch/a.out")
url_b=$(tail -n 1 "$scratch/b.out")
port_a=$(port_of "$url_a")
port_b=$(port_of "$url_b")
ok "start printed $url_a and $url_b as the last lines on stdout"
[ "$(wc -l <"$scratch/a.out")" -eq 1 ] || fail "start wrote more than the URL to stdout: $(cat "$scratch/a.out")"
ok "start wrote only the URL to stdout"
[ "$port_a" != "$port_b" ] || fail "both clusters got port $port_a"
ok "the two clusters have different ports ($port_a, $port_b)"
[ "$("$PG" url "$dir_a")" = "$url_a" ] || fail "tools/postgres url $dir_a is not $url_a"
ok "url prints the URL"

# --- PostGIS through the URL ------------------------------------------------------------------
version=$(sql "$url_a" -c 'SELECT postgis_full_version()') || fail "SELECT postgis_full_version() failed"
[[ "$version" == POSTGIS=\"3.* ]] || fail "postgis_full_version() is '$version'"
ok "postgis_full_version(): ${version%% \[*}"
sql "$url_a" <<'EOF' || fail "creating and filling the geometry(Point,4326) table failed"
CREATE TABLE probe (id serial PRIMARY KEY, geom geometry(Point, 4326) NOT NULL);
CREATE INDEX probe_geom ON probe USING gist (geom);
INSERT INTO probe (geom)
  SELECT ST_SetSRID(ST_MakePoint(11.0 + i * 0.001, 48.0), 4326) FROM generate_series(0, 999) i;
ANALYZE probe;
EOF
near=$(sql "$url_a" -c \
  "SELECT count(*) FROM probe WHERE ST_DWithin(geom, ST_SetSRID(ST_MakePoint(11.0, 48.0), 4326), 0.0025)")
[ "$near" = 3 ] || fail "ST_DWithin found $near points within 0.0025 degrees, expected 3"
ok "ST_DWithin on geometry(Point,4326) finds the 3 nearby points"
plan=$(sql "$url_a" -c "SET enable_seqscan = off" -c \
  "EXPLAIN SELECT id FROM probe WHERE ST_DWithin(geom, ST_SetSRID(ST_MakePoint(11.0, 48.0), 4326), 0.0025)")
grep -q probe_geom <<<"$plan" || fail "the ST_DWithin query does not use the GiST index: $plan"
ok "the ST_DWithin query uses the GiST index"
[ "$(sql "$url_b" -c "SELECT extname FROM pg_extension WHERE extname = 'postgis'")" = postgis ] ||
  fail "the second cluster has no postgis extension"
ok "the second cluster has postgis too"
[ "$(sql "$url_a" -c 'SHOW fsync')" = off ] || fail "--fast did not turn fsync off"
[ "$(sql "$url_a" -c 'SHOW listen_addresses')" = 127.0.0.1 ] || fail "listen_addresses is not 127.0.0.1"
ok "--fast turned fsync off; the server listens on 127.0.0.1 only"
socket_a=$(cat "$dir_a/socket_dir")
[ "$socket_a" = "$dir_a/socket" ] || fail "the socket directory of $dir_a is $socket_a, not $dir_a/socket"
[ "$("$PSQL" -X -At -h "$socket_a" -p "$port_a" -U polmap -d polmap -c 'SELECT 1')" = 1 ] ||
  fail "no connection through the Unix socket in $socket_a"
ok "the Unix socket in DIR/socket accepts connections"

# --- status, start on a running cluster, stop -------------------------------------------------
[ "$(status_of "$dir_a")" = "running|0" ] || fail "status of a running cluster: $(status_of "$dir_a")"
[ "$("$PG" status "$dir_a" 2>/dev/null | tail -n 1)" = "$url_a" ] || fail "status does not print the URL"
ok "status says running (exit 0) and prints the URL"
rc=0
"$PG" start --fast "$dir_a" >/dev/null 2>&1 || rc=$?
[ "$rc" -eq 1 ] || fail "start on a running cluster exited $rc, expected 1"
ok "start refuses a running cluster (exit 1)"
"$PG" stop "$dir_a" 2>/dev/null || fail "tools/postgres stop $dir_a failed"
[ "$(status_of "$dir_a")" = "stopped|3" ] || fail "status of a stopped cluster: $(status_of "$dir_a")"
ok "status says stopped (exit 3) after stop"
! port_open "$port_a" || fail "port $port_a still accepts connections after stop"
ok "port $port_a is closed after stop"
[ -z "$("$PG" stop "$dir_a" 2>&1)" ] || fail "a second stop was not quiet"
ok "a second stop succeeds quietly"
port_open "$port_b" || fail "stopping A stopped B (port $port_b closed)"
ok "the other cluster still runs"

# --- restart keeps the data --------------------------------------------------------------------
url_a2=$("$PG" start --fast "$dir_a" 2>/dev/null | tail -n 1) || fail "restarting $dir_a failed"
port_of "$url_a2" >/dev/null
[ "$(sql "$url_a2" -c 'SELECT count(*) FROM probe')" = 1000 ] || fail "the restarted cluster lost its rows"
ok "start on a stopped cluster restarts it with its data ($url_a2)"
[ "$(sql "$url_a2" -c 'SHOW fsync')" = off ] || fail "the restart with --fast has fsync on"
"$PG" stop "$dir_a" 2>/dev/null || fail "stopping the restarted cluster failed"
"$PG" stop "$dir_b" 2>/dev/null || fail "tools/postgres stop $dir_b failed"
! port_open "$port_b" || fail "port $port_b still accepts connections after stop"
ok "both clusters stopped"

# --- a directory too long for a Unix socket path ----------------------------------------------
new_dir long "${TMPDIR:-/tmp}/polmap-pgtest-$(printf 'l%.0s' {1..90}).XXXXXX"
url_l=$("$PG" start --fast "$long" 2>/dev/null | tail -n 1) || fail "start in a long directory failed"
port_l=$(port_of "$url_l")
socket_l=$(cat "$long/socket_dir")
[[ "$socket_l" == /tmp/polmap-pg.* ]] || fail "the long directory's socket is in $socket_l, not under /tmp"
[ "$("$PSQL" -X -At -h "$socket_l" -p "$port_l" -U polmap -d polmap -c 'SELECT 1')" = 1 ] ||
  fail "no connection through the Unix socket in $socket_l"
"$PG" stop "$long" 2>/dev/null || fail "stopping the long directory's cluster failed"
[ ! -e "$socket_l" ] || fail "stop left the socket directory $socket_l behind"
ok "a ${#long}-byte directory gets its socket in $socket_l, removed by stop"

echo "postgres_script_test: $passed passed, 0 failed in $((SECONDS - start_s)) s"
