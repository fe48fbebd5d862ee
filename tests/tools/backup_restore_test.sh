#!/usr/bin/env bash
# tools/backup and tools/restore end to end, for both backends: a store is filled through
# `polmap serve` (two simulated drives uploaded, a map built), backed up while the server
# runs and serves tiles, restored into a fresh location, and the copy is compared with the
# original: drives (ids, content hashes), map versions (status, statistics), every tile's
# bytes and ETag (sqlite3 / psql) and `polmap export` of the current map. PostgreSQL runs
# in a throw-away cluster (tools/postgres start --fast). Needs a built tree (POLMAP_BIN
# overrides build/tools/polmap); fails, never skips, without PostgreSQL.
set -euo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
POLMAP=${POLMAP_BIN:-$ROOT/build/tools/polmap}
PG=$ROOT/tools/postgres
start_s=$SECONDS
[ -x "$POLMAP" ] || { echo "backup_restore_test: $POLMAP not built" >&2; exit 1; }
W=$(mktemp -d /tmp/polmap-backup-test.XXXXXX)
PGDIR=$(mktemp -d /tmp/polmap-backup-pg.XXXXXX)  # its own mktemp dir: polmap-pg must reach it as root
SERVER_PID=""
cleanup() {
  local rc=$?
  [ -z "$SERVER_PID" ] || kill "$SERVER_PID" 2>/dev/null || true
  "$PG" stop "$PGDIR" >/dev/null 2>&1 || true
  rm -rf -- "$W" "$PGDIR"
  [ "$rc" -eq 0 ] || echo "backup_restore_test: FAILED (exit $rc)" >&2
}
trap cleanup EXIT
trap 'exit 143' TERM
fail() { echo "backup_restore_test: FAIL: $*" >&2; exit 1; }

KEY=backup-test-operator-key
echo "operator $KEY" > "$W/keys"
"$POLMAP" simulate --realism ideal --world urban --length-m 200 --drives 2 --seed 3 --out "$W/sim" >/dev/null
for i in 0 1; do
  "$POLMAP" process --recording "$W/sim/drive_$i.pmrec" --out "$W/drive_$i.tar" --tar >/dev/null
done
URL=$("$PG" start --fast "$PGDIR" 2>"$W/pg.log" | tail -n 1)
case "$URL" in postgresql://*) ;; *) cat "$W/pg.log" >&2; fail "tools/postgres start: no URL" ;; esac

start_server() {  # DB [serve args...]
  : > "$W/server.log"
  "$POLMAP" serve --db "$@" --listen 127.0.0.1:0 --api-key-file "$W/keys" 2>>"$W/server.log" &
  SERVER_PID=$!
  for _ in $(seq 1 400); do
    PORT=$(grep -o 'listening on http://127.0.0.1:[0-9]*' "$W/server.log" | grep -o '[0-9]*$' || true)
    if [ -n "$PORT" ] && curl -fsS -o /dev/null "http://127.0.0.1:$PORT/health" 2>/dev/null; then return 0; fi
    sleep 0.05
  done
  cat "$W/server.log" >&2; fail "server did not come up"
}
stop_server() { kill "$SERVER_PID"; wait "$SERVER_PID" 2>/dev/null || true; SERVER_PID=""; }

fill() {  # uploads both drives and builds a map through the running server
  local u="http://127.0.0.1:$PORT"
  for i in 0 1; do
    code=$(curl -sS -o "$W/resp" -w '%{http_code}' -X POST -H "Authorization: Bearer $KEY" \
      -H 'Content-Type: application/x-tar' --data-binary "@$W/drive_$i.tar" "$u/v1/drives")
    [ "$code" = 201 ] || { cat "$W/resp" >&2; fail "upload drive_$i: HTTP $code"; }
  done
  code=$(curl -sS -o "$W/resp" -w '%{http_code}' -X POST -H "Authorization: Bearer $KEY" \
    -H 'Content-Type: application/json' --data '{}' "$u/v1/maps")
  [ "$code" = 202 ] || { cat "$W/resp" >&2; fail "build: HTTP $code"; }
  for _ in $(seq 1 600); do
    if curl -fsS "$u/v1/maps/current" 2>/dev/null | grep -q '"published"'; then return 0; fi
    sleep 0.1
  done
  fail "the map build did not publish"
}

# What must survive, per backend: q runs SQL on a store and prints rows.
snapshot() {  # q-function DB OUT
  local q=$1 db=$2 out=$3
  {
    "$q" "$db" "SELECT id, drive_id, content_hash, package_bytes FROM drives ORDER BY id"
    "$q" "$db" "SELECT version, status, published_at, statistics_json FROM map_versions ORDER BY version"
    "$q" "$db" "SELECT version FROM current_map"
    for t in tiles gridmap_tiles gridmap_mechanism_tiles; do
      "$q" "$db" "SELECT t.version, t.z, t.x, t.y, b.etag, $(hexfn "$q")(b.payload) FROM $t t JOIN tile_blobs b ON b.id = t.blob ORDER BY 1, 2, 3, 4"
    done
    "$q" "$db" "SELECT COUNT(*) FROM landmarks"
  } > "$out"
}
hexfn() { if [ "$1" = q_pg ]; then echo "encode"; else echo "hex"; fi; }
q_sqlite() { sqlite3 "$1" "$2"; }
q_pg() {
  local sql=$2
  sql=${sql//encode(b.payload)/encode(b.payload, \'hex\')}
  sql=${sql//encode(payload)/encode(payload, \'hex\')}
  psql "$1" -XAtq -v ON_ERROR_STOP=1 -c "$sql"
}

check_copy() {  # backend q-function original restored
  local name=$1 q=$2 a=$3 b=$4
  snapshot "$q" "$a" "$W/$name.orig"
  snapshot "$q" "$b" "$W/$name.restored"
  [ "$(grep -c . "$W/$name.orig")" -gt 5 ] || fail "$name: the original store is nearly empty"
  grep -q '|published|' "$W/$name.orig" || fail "$name: no published version"
  cmp -s "$W/$name.orig" "$W/$name.restored" || { diff "$W/$name.orig" "$W/$name.restored" | head >&2; fail "$name: restored rows differ"; }
  # Every tile blob's ETag is the SHA-256 of its payload (restored bytes, not just equal hex).
  while IFS='|' read -r etag hex; do
    [ "$(printf '%s' "$hex" | xxd -r -p | sha256sum | cut -d' ' -f1)" = "$etag" ] || fail "$name: tile $etag does not hash to its ETag"
  done < <("$q" "$b" "SELECT etag, $(hexfn "$q")(payload) FROM tile_blobs")
  "$POLMAP" export --db "$a" --format geojson --out "$W/$name.orig.geojson" >/dev/null
  "$POLMAP" export --db "$b" --format geojson --out "$W/$name.restored.geojson" >/dev/null
  cmp -s "$W/$name.orig.geojson" "$W/$name.restored.geojson" || fail "$name: export differs"
  echo "backup_restore_test: $name ok ($(grep -c . "$W/$name.orig") rows compared)"
}

# Tile reads keep going while the backup runs.
reader() { while :; do curl -s -o /dev/null "http://127.0.0.1:$PORT/v1/tilejson.json" || true; done; }

# --- SQLite
start_server "$W/map.db"
fill
reader & READER=$!
"$ROOT/tools/backup" --db "$W/map.db" --out "$W/backup_sqlite" >/dev/null
kill "$READER"; wait "$READER" 2>/dev/null || true
stop_server
"$ROOT/tools/backup" --db "$W/map.db" --out "$W/backup_sqlite" >/dev/null 2>&1 && fail "backup into a non-empty directory succeeded"
"$ROOT/tools/restore" --from "$W/backup_sqlite" --db "$W/restored.db" >/dev/null
"$ROOT/tools/restore" --from "$W/backup_sqlite" --db "$W/restored.db" >/dev/null 2>&1 && fail "restore over an existing store succeeded"
check_copy sqlite q_sqlite "$W/map.db" "$W/restored.db"

# --- PostgreSQL
start_server "$URL" --package-dir "$W/pkg"
fill
reader & READER=$!
"$ROOT/tools/backup" --db "$URL" --out "$W/backup_pg" >/dev/null
kill "$READER"; wait "$READER" 2>/dev/null || true
stop_server
psql "$URL" -XAtq -c "CREATE DATABASE restored" >/dev/null
RURL=${URL%/*}/restored
"$ROOT/tools/restore" --from "$W/backup_pg" --db "$RURL" --package-dir "$W/pkg_restored" >/dev/null
[ "$(psql "$RURL" -XAtq -c "SELECT value FROM store_settings WHERE key = 'package_dir'")" = "$W/pkg_restored" ] ||
  fail "postgres: the restored store does not record its new package directory"
"$ROOT/tools/restore" --from "$W/backup_pg" --db "$RURL" --package-dir "$W/pkg_other" >/dev/null 2>&1 &&
  fail "restore into a non-empty database succeeded"
check_copy postgres q_pg "$URL" "$RURL"
# The restored store serves: a server opens it and answers the same current version.
start_server "$RURL"
curl -fsS "http://127.0.0.1:$PORT/v1/maps/current" | grep -q '"published"' || fail "postgres: restored store does not serve its map"
stop_server
echo "backup_restore_test: ok ($((SECONDS - start_s)) s)"
