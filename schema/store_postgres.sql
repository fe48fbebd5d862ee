-- polmap map store schema for PostgreSQL 15 + PostGIS 3 (PostgresMapStore,
-- mapping_service/store/src/postgres_store.cpp, which embeds these exact statements; the
-- store tests check this file against them). The tables are those of schema/store.sql (see
-- its comments for what each holds); this file tells only where PostgreSQL differs.
--
-- Versioning: as store.sql. Every open runs, in ONE transaction under
-- pg_advisory_xact_lock (so several replicas opening at once do not race), the bootstrap
-- statements, then each migration whose number is above MAX(schema_migrations.version),
-- recording it in schema_migrations. Migrations are append-only: a released migration is
-- never edited; changes come as a new numbered migration at the end of this file. The
-- numbers are this file's own (migration 1 is the whole schema of store.sql's migration 7).
--
-- Conventions (differences from store.sql):
--   * geodetic coordinates: WGS84 degrees in double precision columns (lat_deg, lon_deg),
--     as in SQLite, plus a PostGIS geometry (SRID 4326, x = lon, y = lat) with a GiST index
--     instead of the *_rtree side tables: a region query is `geom && ST_MakeEnvelope(...)`
--     (bounding boxes in single precision, rounded outward: a superset), then the exact test
--     on the double precision columns, as SQLite does after its R*Tree, so both return the
--     same rows. candidates.geom / landmarks.geom: a Point (kind 0) or a LineString (kind 1);
--     drives.bbox: the envelope Polygon of the drive's bounding box;
--   * ids that the interface returns (drives.id, candidates.id, map_versions.version,
--     landmarks.id) are assigned by the store as MAX + 1 under the store's write lock, as
--     SQLite assigns rowids, so both backends number rows alike; tile_blobs.id is internal
--     (an identity column);
--   * times: ISO 8601 UTC text ("2024-05-01T12:00:00Z"), written by the store, identical to
--     SQLite's; compared and sorted in the "C" collation (byte order);
--   * JSON: jsonb columns named *_json (PostgreSQL cannot store "\u0000" in jsonb);
--   * blobs: bytea;
--   * text keys that are sorted (content hashes, upload session ids) use COLLATE "C";
--   * a drive's package files live in <package_dir>/<content_hash>/ and upload session files
--     in <package_dir>/uploads/ (package_dir: a directory every replica reaches, recorded in
--     store_settings at the first open).
--
-- Tables only here:
--   store_settings    key/value settings of the store: 'package_dir' (absolute path).

-- bootstrap (every open)
CREATE TABLE IF NOT EXISTS schema_migrations (
  version    integer PRIMARY KEY,
  name       text NOT NULL,
  applied_at text NOT NULL
);

-- migration 1: initial schema
CREATE EXTENSION IF NOT EXISTS postgis;

CREATE TABLE store_settings (
  key   text PRIMARY KEY,
  value text NOT NULL
);

CREATE TABLE drives (
  id            bigint PRIMARY KEY,
  drive_id      text NOT NULL UNIQUE,
  content_hash  text COLLATE "C" NOT NULL UNIQUE,
  vehicle_id    text NOT NULL,
  start_time_s  double precision NOT NULL,
  end_time_s    double precision NOT NULL,
  min_lat_deg   double precision NOT NULL,
  min_lon_deg   double precision NOT NULL,
  max_lat_deg   double precision NOT NULL,
  max_lon_deg   double precision NOT NULL,
  bbox          geometry(Polygon, 4326) NOT NULL,
  pol_level     text NOT NULL,
  distance_m    double precision NOT NULL,
  num_points    bigint NOT NULL,
  num_lines     bigint NOT NULL,
  manifest_json jsonb NOT NULL,
  package_path  text NOT NULL,
  package_bytes bigint NOT NULL,
  ingested_at   text COLLATE "C" NOT NULL
);
CREATE INDEX drives_bbox ON drives USING gist (bbox);

CREATE TABLE candidates (
  id          bigint PRIMARY KEY,
  drive       bigint NOT NULL REFERENCES drives(id) ON DELETE CASCADE,
  kind        integer NOT NULL CHECK (kind IN (0, 1)),
  lat_deg     double precision NOT NULL,
  lon_deg     double precision NOT NULL,
  x_m         double precision NOT NULL,
  y_m         double precision NOT NULL,
  end_lat_deg double precision,
  end_lon_deg double precision,
  end_x_m     double precision,
  end_y_m     double precision,
  strength    double precision NOT NULL,
  power_db    double precision,
  scattering  integer,
  num_cells   bigint,
  geom        geometry(Geometry, 4326) NOT NULL
              CHECK (GeometryType(geom) = CASE kind WHEN 0 THEN 'POINT' ELSE 'LINESTRING' END)
);
CREATE INDEX candidates_drive ON candidates(drive);
CREATE INDEX candidates_geom ON candidates USING gist (geom);

CREATE TABLE map_versions (
  version         bigint PRIMARY KEY,
  status          text NOT NULL CHECK (status IN ('building', 'published', 'failed')),
  created_at      text COLLATE "C" NOT NULL,
  published_at    text,
  parameters_json jsonb NOT NULL,
  statistics_json jsonb,
  error           text
);
CREATE TABLE current_map (
  id      integer PRIMARY KEY CHECK (id = 1),
  version bigint NOT NULL REFERENCES map_versions(version)
);
CREATE FUNCTION current_map_must_be_published() RETURNS trigger LANGUAGE plpgsql AS $$
BEGIN
  IF (SELECT status FROM map_versions WHERE version = NEW.version) IS DISTINCT FROM
      'published' THEN
    RAISE EXCEPTION 'current map version must be published';
  END IF;
  RETURN NEW;
END $$;
CREATE TRIGGER current_map_published BEFORE INSERT OR UPDATE ON current_map
  FOR EACH ROW EXECUTE FUNCTION current_map_must_be_published();

CREATE TABLE landmarks (
  id             bigint PRIMARY KEY,
  version        bigint NOT NULL REFERENCES map_versions(version) ON DELETE CASCADE,
  key            bigint NOT NULL,
  kind           integer NOT NULL CHECK (kind IN (0, 1)),
  lat_deg        double precision NOT NULL,
  lon_deg        double precision NOT NULL,
  polyline_json  jsonb,
  scattering     integer NOT NULL DEFAULT 0,
  support_drives bigint NOT NULL,
  spread_m       double precision NOT NULL,
  support_of     bigint,
  geom           geometry(Geometry, 4326) NOT NULL
                 CHECK (GeometryType(geom) = CASE kind WHEN 0 THEN 'POINT' ELSE 'LINESTRING' END)
);
CREATE INDEX landmarks_version ON landmarks(version, kind);
CREATE INDEX landmarks_geom ON landmarks USING gist (geom);
CREATE INDEX landmarks_support_of ON landmarks(support_of) WHERE support_of IS NOT NULL;

CREATE TABLE landmark_support (
  landmark  bigint NOT NULL REFERENCES landmarks(id) ON DELETE CASCADE,
  candidate bigint NOT NULL REFERENCES candidates(id) ON DELETE CASCADE,
  PRIMARY KEY (landmark, candidate)
);
CREATE INDEX landmark_support_candidate ON landmark_support(candidate);

CREATE TABLE landmark_changes (
  version                bigint NOT NULL REFERENCES map_versions(version) ON DELETE CASCADE,
  seq                    bigint NOT NULL,
  change                 text NOT NULL CHECK (change IN ('added', 'moved', 'retired')),
  kind                   integer NOT NULL CHECK (kind IN (0, 1)),
  key                    bigint NOT NULL,
  previous_key           bigint NOT NULL,
  distance_m             double precision NOT NULL,
  geometry_json          jsonb NOT NULL,
  previous_geometry_json jsonb NOT NULL,
  reason_json            jsonb NOT NULL,
  PRIMARY KEY (version, seq)
);
CREATE INDEX landmark_changes_key ON landmark_changes(key);

CREATE TABLE tile_blobs (
  id        bigint GENERATED BY DEFAULT AS IDENTITY PRIMARY KEY,
  etag      text COLLATE "C" NOT NULL UNIQUE,
  payload   bytea NOT NULL,
  byte_size bigint NOT NULL
);
CREATE TABLE tiles (
  version    bigint NOT NULL REFERENCES map_versions(version) ON DELETE CASCADE,
  z          integer NOT NULL,
  x          integer NOT NULL,
  y          integer NOT NULL,
  blob       bigint NOT NULL REFERENCES tile_blobs(id),
  num_points integer NOT NULL DEFAULT 0,
  num_lines  integer NOT NULL DEFAULT 0,
  PRIMARY KEY (version, z, x, y)
);
CREATE INDEX tiles_blob ON tiles(blob);
CREATE TABLE gridmap_tiles (
  version    bigint NOT NULL REFERENCES map_versions(version) ON DELETE CASCADE,
  z          integer NOT NULL,
  x          integer NOT NULL,
  y          integer NOT NULL,
  blob       bigint NOT NULL REFERENCES tile_blobs(id),
  num_points integer NOT NULL DEFAULT 0,
  num_lines  integer NOT NULL DEFAULT 0,
  PRIMARY KEY (version, z, x, y)
);
CREATE INDEX gridmap_tiles_blob ON gridmap_tiles(blob);
CREATE TABLE gridmap_mechanism_tiles (
  version    bigint NOT NULL REFERENCES map_versions(version) ON DELETE CASCADE,
  z          integer NOT NULL,
  x          integer NOT NULL,
  y          integer NOT NULL,
  blob       bigint NOT NULL REFERENCES tile_blobs(id),
  num_points integer NOT NULL DEFAULT 0,
  num_lines  integer NOT NULL DEFAULT 0,
  PRIMARY KEY (version, z, x, y)
);
CREATE INDEX gridmap_mechanism_tiles_blob ON gridmap_mechanism_tiles(blob);

CREATE TABLE drive_trajectories (
  drive         bigint PRIMARY KEY REFERENCES drives(id) ON DELETE CASCADE,
  min_spacing_m double precision NOT NULL,
  samples_json  jsonb NOT NULL,
  path_blob     bytea
);

CREATE TABLE upload_sessions (
  id           text COLLATE "C" PRIMARY KEY CHECK (length(id) = 32),
  owner        text NOT NULL,
  length_bytes bigint NOT NULL CHECK (length_bytes > 0),
  offset_bytes bigint NOT NULL DEFAULT 0
               CHECK (offset_bytes >= 0 AND offset_bytes <= length_bytes),
  sha256       text,
  created_at   text COLLATE "C" NOT NULL,
  expires_at   text COLLATE "C" NOT NULL,
  file_path    text NOT NULL
);
CREATE INDEX upload_sessions_owner ON upload_sessions(owner, expires_at);
CREATE INDEX upload_sessions_expires ON upload_sessions(expires_at);

CREATE TABLE gridmap_sums (
  level      integer NOT NULL,
  x          integer NOT NULL,
  y          integer NOT NULL,
  data       bytea NOT NULL,
  updated_by bigint NOT NULL,
  PRIMARY KEY (level, x, y)
);
CREATE INDEX gridmap_sums_updated ON gridmap_sums(updated_by);
CREATE TABLE gridmap_sum_inputs (
  content_hash text COLLATE "C" PRIMARY KEY,
  tiles        bigint NOT NULL,
  added_at     text NOT NULL
);
CREATE TABLE gridmap_sum_cover (
  content_hash text COLLATE "C" NOT NULL
               REFERENCES gridmap_sum_inputs(content_hash) ON DELETE CASCADE,
  level        integer NOT NULL,
  x            integer NOT NULL,
  y            integer NOT NULL,
  PRIMARY KEY (content_hash, level, x, y)
);
CREATE INDEX gridmap_sum_cover_tile ON gridmap_sum_cover(level, x, y);

-- migration 2: partitioned map builds (store.sql migration 8)
-- lease_until is seconds since the epoch on the database server's clock, so workers on
-- several hosts agree.
CREATE TABLE build_jobs (
  job_id      bigint PRIMARY KEY,
  version     bigint NOT NULL REFERENCES map_versions(version) ON DELETE CASCADE,
  kind        text NOT NULL CHECK (kind IN ('region', 'gridmap', 'publish')),
  z           integer NOT NULL,
  x           integer NOT NULL,
  y           integer NOT NULL,
  spec_json   jsonb NOT NULL,
  state       text NOT NULL CHECK (state IN ('pending', 'running', 'done', 'failed')),
  attempt     integer NOT NULL DEFAULT 0,
  worker      text NOT NULL DEFAULT '',
  lease_until double precision NOT NULL DEFAULT 0,
  result_json jsonb,
  error       text NOT NULL DEFAULT ''
);
CREATE INDEX build_jobs_claim ON build_jobs(state, job_id);
CREATE INDEX build_jobs_version ON build_jobs(version, kind, state);

-- migration 3: localization run reports and their quality cells (store.sql migration 9)
CREATE TABLE localization_runs (
  id           bigint PRIMARY KEY,
  received_at  text NOT NULL,
  vehicle_id   text NOT NULL,
  map_version  bigint NOT NULL,
  label        text NOT NULL,
  samples      bigint NOT NULL,
  min_lat_deg  double precision NOT NULL,
  min_lon_deg  double precision NOT NULL,
  max_lat_deg  double precision NOT NULL,
  max_lon_deg  double precision NOT NULL,
  summary_json jsonb NOT NULL,
  body         bytea NOT NULL
);
CREATE INDEX localization_runs_vehicle ON localization_runs(vehicle_id, id);
CREATE TABLE localization_run_cells (
  run               bigint NOT NULL REFERENCES localization_runs(id) ON DELETE CASCADE,
  z                 integer NOT NULL,
  x                 integer NOT NULL,
  y                 integer NOT NULL,
  samples           bigint NOT NULL,
  degraded          bigint NOT NULL,
  evaluated         bigint NOT NULL,
  sum_sigma_lat_m   double precision NOT NULL,
  sum_err_lat2_m2   double precision NOT NULL,
  max_abs_err_lat_m double precision NOT NULL,
  PRIMARY KEY (run, z, x, y)
);
CREATE INDEX localization_run_cells_tile ON localization_run_cells(z, x, y);

-- migration 4: HD-map comparisons (store.sql migration 10); landmarks by key
CREATE TABLE hdmap_comparisons (
  version       bigint NOT NULL REFERENCES map_versions(version) ON DELETE CASCADE,
  name          text COLLATE "C" NOT NULL,
  hdmap_file    text NOT NULL,
  created_at    text NOT NULL,
  summary_json  jsonb NOT NULL,
  features_json jsonb NOT NULL,
  PRIMARY KEY (version, name)
);
CREATE INDEX landmarks_key ON landmarks(key, version);

-- migration 5: gridmap_sum_inputs.placement (store.sql migration 11)
ALTER TABLE gridmap_sum_inputs ADD COLUMN placement text NOT NULL DEFAULT '';

-- migration 6: upload_sessions.outcome_* (store.sql migration 12)
ALTER TABLE upload_sessions ADD COLUMN outcome_status integer NOT NULL DEFAULT 0;
ALTER TABLE upload_sessions ADD COLUMN outcome_location text NOT NULL DEFAULT '';
ALTER TABLE upload_sessions ADD COLUMN outcome_body text NOT NULL DEFAULT '';
