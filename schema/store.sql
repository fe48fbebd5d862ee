-- polmap map store schema (SQLite 3.24+ with the R*Tree module; Debian's libsqlite3 has it).
-- Applied by SqliteMapStore (mapping_service/src/sqlite_store.cpp), which embeds these exact
-- statements; tests/mapping_service/sqlite_store_test.cpp checks this file against them.
--
-- Versioning: every open first runs the bootstrap statement, then, in ONE
-- transaction, each migration whose number is above MAX(schema_migrations.version),
-- recording it in schema_migrations. Migrations are append-only: a released migration
-- is never edited; changes come as a new numbered migration at the end of this file.
--
-- Conventions:
--   * geodetic coordinates: WGS84 degrees (lat_deg, lon_deg) in REAL columns;
--   * *_rtree: R*Tree side tables (id = row id of the main table) holding 32-bit float
--     bounding boxes (min_lat, max_lat, min_lon, max_lon) rounded outward; queries use them
--     as a coarse filter and then test the exact REAL columns. R*Tree tables cannot take
--     foreign keys, so AFTER DELETE triggers keep them in step (FK cascades fire them);
--   * times: ISO 8601 UTC text ("2024-05-01T12:00:00Z"), which sorts chronologically;
--   * JSON: TEXT columns named *_json;
--   * a drive's package files live in <db>.drives/<content_hash>/ (package_path is
--     relative to that drive store directory).
--
-- Tables:
--   drives            one row per ingested package; drive_id (manifest) and content_hash
--                     (SHA-256 hex of the uploaded bytes) are both unique: a second upload
--                     of the same bytes is a no-op, the same drive_id with other bytes a
--                     conflict.
--   candidates        landmark candidates of a drive: kind 0 = point (lat/lon, x/y), kind 1 =
--                     line (start lat/lon, x/y; end_* columns). x_m/y_m are in the drive's
--                     LocalFrame (manifest origin). Deleted with their drive (cascade).
--   map_versions      one row per build: status building -> published | failed. Published
--                     versions are immutable snapshots. parameters_json holds the build
--                     request (region, excluded drives, config, notes), statistics_json the
--                     build statistics.
--   current_map       single-row pointer (id = 1) to the published version served by default;
--                     triggers refuse a pointer to a version that is not published. Publishing
--                     updates map_versions.status and current_map in one transaction, so
--                     readers see either the old or the new map, never half of one.
--   landmarks         consensus landmarks of a version: kind 0 = point at (lat_deg, lon_deg),
--                     kind 1 = line with polyline_json = [[lat, lon], ...] (>= 2 vertices;
--                     lat/lon = first vertex). key = stable id (hash of the quantized
--                     geometry), identical for an unchanged landmark in the next version.
--   landmark_support  landmark -> supporting candidate ids (provenance). Deleting a drive
--                     removes its links; landmarks of published versions stay. A landmark
--                     copied unchanged by an incremental build has support_of = the landmark
--                     whose links it shares (deleting that version hands them to the copy).
--   gridmap_mechanism_tiles  (migration 6) the fleet gridmap's scattering-mechanism
--                     colouring, like gridmap_tiles (fleet_gridmap.hpp).
--   gridmap_sums      (migration 7) the merged PreCFAR gridmap, state of the store rather than
--                     of a version: per polarimetric level and z20 Web-Mercator tile (256 × 256
--                     cells of ≈ 0.1 m) the per-cell sums Σ N, Σ N·σ² and Σ N·C_ij over every
--                     drive in gridmap_sum_inputs (bytes: gridmap_sums_codec.hpp). updated_by =
--                     the map version whose build last wrote the tile, so a build re-renders only
--                     what changed since the version it follows. A tile whose drives are all
--                     removed stays as an empty tile (it keeps its updated_by).
--   gridmap_sum_inputs (migration 7) the drives (by package hash) whose gridmap is in the sums;
--                     gridmap_sum_cover the sum tiles each touched; placement (migration 11)
--                     how its gridmap was placed (build/drive_placement.hpp). Not tied to drives by a
--                     foreign key: a deleted drive stays an input until the next build takes
--                     its contribution out (recomputing its tiles from the remaining inputs).
--   localization_runs (migration 9) localization run reports sent by vehicles (POST /v1/runs,
--                     schema/localization_run.md): the list's columns, the server's summary and
--                     the canonical report bytes (body). The newest N are kept.
--   localization_run_cells (migration 9) a run's samples binned into Web-Mercator tiles
--                     (zoom z): sums that add up over runs for the fleet-wide quality layer.
--                     Deleted with their run (cascade).
--   landmark_changes  (migration 4) per map version: landmarks added, moved or retired against the version
--                     current when its build started, with the builder's reason (JSON).
--   hdmap_comparisons (migration 10) per published map version and HD-map name: a comparison
--                     with a Lanelet2 HD map (polmap compare-hdmap --store): summary_json = the
--                     metrics and parameters, features_json = a GeoJSON FeatureCollection of
--                     matched / unmatched HD features and landmarks. Replaced by a new run of
--                     the same name; deleted with its version (cascade).
--   tile_blobs        content-addressed tile payloads: etag = SHA-256 hex of payload, unique,
--                     so an unchanged tile shared by many versions is stored once (and keeps
--                     its ETag, so vehicle caches stay valid across versions). Blobs no
--                     longer referenced are deleted with their last version.
--   tiles             localization tiles of a version (z = tiles::kLocalizationZoom, XYZ keys)
--   gridmap_tiles     fleet gridmap raster tiles of a version (fleet_gridmap.hpp documents
--                     the payload), same shape as tiles.
--   drive_trajectories (migration 2) a drive's trajectory decimated at ingest to one sample per
--                     metre travelled (at least one per 5 s): samples_json = [[time_s, lat_deg,
--                     lon_deg, yaw_enu_rad, speed_mps], ...]; for map display (MVT, TileJSON
--                     bounds) without opening the package. Drives ingested before migration 2
--                     have no row. path_blob (migration 5): the whole trajectory's positions
--                     simplified by Douglas-Peucker to 0.25 m, little-endian float64 (lat, lon)
--                     pairs: what map builds read (MapStore::drive_path); NULL for drives
--                     ingested before migration 5 (simplified from samples_json on read).
--   upload_sessions   (migration 3) resumable uploads in progress (POST /v1/uploads): id = 128
--                     random bits as 32 lower-case hex digits; owner = fingerprint (SHA-256 hex)
--                     of the API key that created it, never the key; the package's declared
--                     length_bytes and optional sha256; offset_bytes = bytes received, fsynced
--                     to the session file and acknowledged (the truth: bytes of the file beyond
--                     it are cut off before the next chunk); file_path relative to the upload
--                     session directory (<db>.uploads/, beside the drive store, reachable by
--                     every replica). Sessions whose expires_at has passed are swept with their
--                     files; nothing else is. outcome_* (migration 12): once the upload is
--                     over, the answer its last chunk got (status 200-499, Location, JSON
--                     body; status 0 while in progress); the file is removed then, the row
--                     kept until it expires (the answer is repeated to a client that lost it).

-- bootstrap (every open)
CREATE TABLE IF NOT EXISTS schema_migrations (
  version    INTEGER PRIMARY KEY,
  name       TEXT NOT NULL,
  applied_at TEXT NOT NULL
);

-- migration 1: initial schema
CREATE TABLE drives (
  id            INTEGER PRIMARY KEY,
  drive_id      TEXT NOT NULL UNIQUE,
  content_hash  TEXT NOT NULL UNIQUE,
  vehicle_id    TEXT NOT NULL,
  start_time_s  REAL NOT NULL,
  end_time_s    REAL NOT NULL,
  min_lat_deg   REAL NOT NULL,
  min_lon_deg   REAL NOT NULL,
  max_lat_deg   REAL NOT NULL,
  max_lon_deg   REAL NOT NULL,
  pol_level     TEXT NOT NULL,
  distance_m    REAL NOT NULL,
  num_points    INTEGER NOT NULL,
  num_lines     INTEGER NOT NULL,
  manifest_json TEXT NOT NULL,
  package_path  TEXT NOT NULL,
  package_bytes INTEGER NOT NULL,
  ingested_at   TEXT NOT NULL
);
CREATE VIRTUAL TABLE drives_rtree USING rtree(id, min_lat, max_lat, min_lon, max_lon);
CREATE TRIGGER drives_rtree_delete AFTER DELETE ON drives BEGIN
  DELETE FROM drives_rtree WHERE id = old.id;
END;

CREATE TABLE candidates (
  id          INTEGER PRIMARY KEY,
  drive       INTEGER NOT NULL REFERENCES drives(id) ON DELETE CASCADE,
  kind        INTEGER NOT NULL CHECK (kind IN (0, 1)),
  lat_deg     REAL NOT NULL,
  lon_deg     REAL NOT NULL,
  x_m         REAL NOT NULL,
  y_m         REAL NOT NULL,
  end_lat_deg REAL,
  end_lon_deg REAL,
  end_x_m     REAL,
  end_y_m     REAL,
  strength    REAL NOT NULL,
  power_db    REAL,
  scattering  INTEGER,
  num_cells   INTEGER
);
CREATE INDEX candidates_drive ON candidates(drive);
CREATE VIRTUAL TABLE candidates_rtree USING rtree(id, min_lat, max_lat, min_lon, max_lon);
CREATE TRIGGER candidates_rtree_delete AFTER DELETE ON candidates BEGIN
  DELETE FROM candidates_rtree WHERE id = old.id;
END;

CREATE TABLE map_versions (
  version         INTEGER PRIMARY KEY,
  status          TEXT NOT NULL CHECK (status IN ('building', 'published', 'failed')),
  created_at      TEXT NOT NULL,
  published_at    TEXT,
  parameters_json TEXT NOT NULL,
  statistics_json TEXT,
  error           TEXT
);
CREATE TABLE current_map (
  id      INTEGER PRIMARY KEY CHECK (id = 1),
  version INTEGER NOT NULL REFERENCES map_versions(version)
);
CREATE TRIGGER current_map_insert BEFORE INSERT ON current_map
WHEN (SELECT status FROM map_versions WHERE version = new.version) IS NOT 'published' BEGIN
  SELECT RAISE(ABORT, 'current map version must be published');
END;
CREATE TRIGGER current_map_update BEFORE UPDATE ON current_map
WHEN (SELECT status FROM map_versions WHERE version = new.version) IS NOT 'published' BEGIN
  SELECT RAISE(ABORT, 'current map version must be published');
END;

CREATE TABLE landmarks (
  id             INTEGER PRIMARY KEY,
  version        INTEGER NOT NULL REFERENCES map_versions(version) ON DELETE CASCADE,
  key            INTEGER NOT NULL,
  kind           INTEGER NOT NULL CHECK (kind IN (0, 1)),
  lat_deg        REAL NOT NULL,
  lon_deg        REAL NOT NULL,
  polyline_json  TEXT,
  scattering     INTEGER NOT NULL DEFAULT 0,
  support_drives INTEGER NOT NULL,
  spread_m       REAL NOT NULL
);
CREATE INDEX landmarks_version ON landmarks(version, kind);
CREATE VIRTUAL TABLE landmarks_rtree USING rtree(id, min_lat, max_lat, min_lon, max_lon);
CREATE TRIGGER landmarks_rtree_delete AFTER DELETE ON landmarks BEGIN
  DELETE FROM landmarks_rtree WHERE id = old.id;
END;

CREATE TABLE landmark_support (
  landmark  INTEGER NOT NULL REFERENCES landmarks(id) ON DELETE CASCADE,
  candidate INTEGER NOT NULL REFERENCES candidates(id) ON DELETE CASCADE,
  PRIMARY KEY (landmark, candidate)
) WITHOUT ROWID;
CREATE INDEX landmark_support_candidate ON landmark_support(candidate);

CREATE TABLE tile_blobs (
  id        INTEGER PRIMARY KEY,
  etag      TEXT NOT NULL UNIQUE,
  payload   BLOB NOT NULL,
  byte_size INTEGER NOT NULL
);
CREATE TABLE tiles (
  version    INTEGER NOT NULL REFERENCES map_versions(version) ON DELETE CASCADE,
  z          INTEGER NOT NULL,
  x          INTEGER NOT NULL,
  y          INTEGER NOT NULL,
  blob       INTEGER NOT NULL REFERENCES tile_blobs(id),
  num_points INTEGER NOT NULL DEFAULT 0,
  num_lines  INTEGER NOT NULL DEFAULT 0,
  PRIMARY KEY (version, z, x, y)
) WITHOUT ROWID;
CREATE INDEX tiles_blob ON tiles(blob);
CREATE TABLE gridmap_tiles (
  version    INTEGER NOT NULL REFERENCES map_versions(version) ON DELETE CASCADE,
  z          INTEGER NOT NULL,
  x          INTEGER NOT NULL,
  y          INTEGER NOT NULL,
  blob       INTEGER NOT NULL REFERENCES tile_blobs(id),
  num_points INTEGER NOT NULL DEFAULT 0,
  num_lines  INTEGER NOT NULL DEFAULT 0,
  PRIMARY KEY (version, z, x, y)
) WITHOUT ROWID;
CREATE INDEX gridmap_tiles_blob ON gridmap_tiles(blob);

-- migration 2: decimated drive trajectories
CREATE TABLE drive_trajectories (
  drive         INTEGER PRIMARY KEY REFERENCES drives(id) ON DELETE CASCADE,
  min_spacing_m REAL NOT NULL,
  samples_json  TEXT NOT NULL
);

-- migration 3: resumable upload sessions
CREATE TABLE upload_sessions (
  id           TEXT PRIMARY KEY CHECK (length(id) = 32),
  owner        TEXT NOT NULL,
  length_bytes INTEGER NOT NULL CHECK (length_bytes > 0),
  offset_bytes INTEGER NOT NULL DEFAULT 0
               CHECK (offset_bytes >= 0 AND offset_bytes <= length_bytes),
  sha256       TEXT,
  created_at   TEXT NOT NULL,
  expires_at   TEXT NOT NULL,
  file_path    TEXT NOT NULL
) WITHOUT ROWID;
CREATE INDEX upload_sessions_owner ON upload_sessions(owner, expires_at);
CREATE INDEX upload_sessions_expires ON upload_sessions(expires_at);

-- migration 4: landmark changes recorded per map version (added, moved, retired, with reasons);
-- landmarks copied by an incremental build share their source's support links (support_of)
CREATE TABLE landmark_changes (
  version                INTEGER NOT NULL REFERENCES map_versions(version) ON DELETE CASCADE,
  seq                    INTEGER NOT NULL,
  change                 TEXT NOT NULL CHECK (change IN ('added', 'moved', 'retired')),
  kind                   INTEGER NOT NULL CHECK (kind IN (0, 1)),
  key                    INTEGER NOT NULL,
  previous_key           INTEGER NOT NULL,
  distance_m             REAL NOT NULL,
  geometry_json          TEXT NOT NULL,
  previous_geometry_json TEXT NOT NULL,
  reason_json            TEXT NOT NULL,
  PRIMARY KEY (version, seq)
) WITHOUT ROWID;
CREATE INDEX landmark_changes_key ON landmark_changes(key);
ALTER TABLE landmarks ADD COLUMN support_of INTEGER;
CREATE INDEX landmarks_support_of ON landmarks(support_of) WHERE support_of IS NOT NULL;

-- migration 5: drive paths (Douglas-Peucker 0.25 m, packed little-endian float64 lat, lon pairs)
ALTER TABLE drive_trajectories ADD COLUMN path_blob BLOB;

-- migration 6: fleet gridmap scattering-mechanism tiles (odd bounce green, even magenta)
CREATE TABLE gridmap_mechanism_tiles (
  version    INTEGER NOT NULL REFERENCES map_versions(version) ON DELETE CASCADE,
  z          INTEGER NOT NULL,
  x          INTEGER NOT NULL,
  y          INTEGER NOT NULL,
  blob       INTEGER NOT NULL REFERENCES tile_blobs(id),
  num_points INTEGER NOT NULL DEFAULT 0,
  num_lines  INTEGER NOT NULL DEFAULT 0,
  PRIMARY KEY (version, z, x, y)
) WITHOUT ROWID;
CREATE INDEX gridmap_mechanism_tiles_blob ON gridmap_mechanism_tiles(blob);

-- migration 7: the merged PreCFAR gridmap: per-cell covariance sums over all drives
CREATE TABLE gridmap_sums (
  level      INTEGER NOT NULL,
  x          INTEGER NOT NULL,
  y          INTEGER NOT NULL,
  data       BLOB NOT NULL,
  updated_by INTEGER NOT NULL,
  PRIMARY KEY (level, x, y)
) WITHOUT ROWID;
CREATE INDEX gridmap_sums_updated ON gridmap_sums(updated_by);
CREATE TABLE gridmap_sum_inputs (
  content_hash TEXT PRIMARY KEY,
  tiles        INTEGER NOT NULL,
  added_at     TEXT NOT NULL
) WITHOUT ROWID;
CREATE TABLE gridmap_sum_cover (
  content_hash TEXT NOT NULL REFERENCES gridmap_sum_inputs(content_hash) ON DELETE CASCADE,
  level        INTEGER NOT NULL,
  x            INTEGER NOT NULL,
  y            INTEGER NOT NULL,
  PRIMARY KEY (content_hash, level, x, y)
) WITHOUT ROWID;
CREATE INDEX gridmap_sum_cover_tile ON gridmap_sum_cover(level, x, y);

-- migration 8: partitioned map builds: jobs claimed by build workers under a lease
-- (one per region, one for the merged gridmap, one to publish; schema/build_jobs.md)
CREATE TABLE build_jobs (
  job_id      INTEGER PRIMARY KEY,
  version     INTEGER NOT NULL REFERENCES map_versions(version) ON DELETE CASCADE,
  kind        TEXT NOT NULL CHECK (kind IN ('region', 'gridmap', 'publish')),
  z           INTEGER NOT NULL,
  x           INTEGER NOT NULL,
  y           INTEGER NOT NULL,
  spec_json   TEXT NOT NULL,
  state       TEXT NOT NULL CHECK (state IN ('pending', 'running', 'done', 'failed')),
  attempt     INTEGER NOT NULL DEFAULT 0,
  worker      TEXT NOT NULL DEFAULT '',
  lease_until REAL NOT NULL DEFAULT 0,
  result_json TEXT,
  error       TEXT NOT NULL DEFAULT ''
);
CREATE INDEX build_jobs_claim ON build_jobs(state, job_id);
CREATE INDEX build_jobs_version ON build_jobs(version, kind, state);

-- migration 9: localization run reports (schema/localization_run.md) and their quality cells
CREATE TABLE localization_runs (
  id           INTEGER PRIMARY KEY,
  received_at  TEXT NOT NULL,
  vehicle_id   TEXT NOT NULL,
  map_version  INTEGER NOT NULL,
  label        TEXT NOT NULL,
  samples      INTEGER NOT NULL,
  min_lat_deg  REAL NOT NULL,
  min_lon_deg  REAL NOT NULL,
  max_lat_deg  REAL NOT NULL,
  max_lon_deg  REAL NOT NULL,
  summary_json TEXT NOT NULL,
  body         BLOB NOT NULL
);
CREATE INDEX localization_runs_vehicle ON localization_runs(vehicle_id, id);
CREATE TABLE localization_run_cells (
  run               INTEGER NOT NULL REFERENCES localization_runs(id) ON DELETE CASCADE,
  z                 INTEGER NOT NULL,
  x                 INTEGER NOT NULL,
  y                 INTEGER NOT NULL,
  samples           INTEGER NOT NULL,
  degraded          INTEGER NOT NULL,
  evaluated         INTEGER NOT NULL,
  sum_sigma_lat_m   REAL NOT NULL,
  sum_err_lat2_m2   REAL NOT NULL,
  max_abs_err_lat_m REAL NOT NULL,
  PRIMARY KEY (run, z, x, y)
) WITHOUT ROWID;
CREATE INDEX localization_run_cells_tile ON localization_run_cells(z, x, y);

-- migration 10: HD-map comparisons stored per map version (polmap compare-hdmap --store);
-- landmarks looked up by their stable key (GET /v1/maps/{v}/landmarks/{key})
CREATE TABLE hdmap_comparisons (
  version       INTEGER NOT NULL REFERENCES map_versions(version) ON DELETE CASCADE,
  name          TEXT NOT NULL,
  hdmap_file    TEXT NOT NULL,
  created_at    TEXT NOT NULL,
  summary_json  TEXT NOT NULL,
  features_json TEXT NOT NULL,
  PRIMARY KEY (version, name)
) WITHOUT ROWID;
CREATE INDEX landmarks_key ON landmarks(key, version);

-- migration 11: how each drive's gridmap was placed into the merged gridmap sums (its
-- alignment correction when it was added; '' = as uploaded), so that a drive whose
-- alignment moves is taken out the way it went in and added again
ALTER TABLE gridmap_sum_inputs ADD COLUMN placement TEXT NOT NULL DEFAULT '';

-- migration 12: a completed upload session keeps the answer its last chunk got (HTTP status,
-- Location, JSON body; status 0 while the upload is in progress) until it expires, so that a
-- client whose connection dropped before that answer arrived can ask again
ALTER TABLE upload_sessions ADD COLUMN outcome_status INTEGER NOT NULL DEFAULT 0;
ALTER TABLE upload_sessions ADD COLUMN outcome_location TEXT NOT NULL DEFAULT '';
ALTER TABLE upload_sessions ADD COLUMN outcome_body TEXT NOT NULL DEFAULT '';
