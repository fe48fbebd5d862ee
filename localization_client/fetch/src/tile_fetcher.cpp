#include "polmap/localization_client/tile_fetcher.hpp"

#include <httplib.h>

#include <algorithm>
#include <charconv>
#include <cmath>
#include <condition_variable>
#include <fstream>
#include <map>
#include <mutex>
#include <sstream>
#include <thread>

#include "polmap/localization_client/tile_cache_file.hpp"
#include "polmap/schema/errors.hpp"
#include "polmap/tiles/publication_manifest.hpp"
#include "polmap/util/cpu_time.hpp"
#include "polmap/util/ed25519.hpp"
#include "polmap/util/file.hpp"
#include "polmap/util/sha256.hpp"

namespace polmap::loc {
namespace {

using SteadyClock = std::chrono::steady_clock;

double unix_now_s() {
  return std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch()).count();
}

/// One cached answer of the server for a tile.
struct Entry {
  tiles::LocalizationTile tile;  ///< empty for 204 / 404
  std::string payload;           ///< encoded tile as received (200 only), for the disk cache
  int http_status = 200;         ///< 200, 204 (covered, no landmarks) or 404 (outside)
  std::string etag;              ///< quoted, as sent by the server ("" for 204/404)
  std::uint64_t header_version = 0;
  double fetched_unix_s = 0.0;  ///< last time the server confirmed it
  bool stale = false;           ///< forced revalidation (new map version seen)
  std::uint64_t last_used = 0;
};

enum Priority : int { kMissing = 0, kPrefetch = 1, kRevalidate = 2 };

struct Job {
  int priority = kMissing;
  SteadyClock::time_point due;
  int attempts = 0;
  std::uint64_t order = 0;  ///< FIFO among equal priority
};

std::filesystem::path cache_path(const std::filesystem::path& dir, const tiles::TileKey& k) {
  return dir / std::to_string(k.z) / std::to_string(k.x) / (std::to_string(k.y) + ".pmtc");
}

tiles::LocalizationTile empty_tile(const tiles::TileKey& key, std::uint64_t version) {
  tiles::LocalizationTile t;
  t.key = key;
  t.map_version = version;
  return t;
}

/// Reads a cache file (tile_cache_file.hpp); nullopt when it is missing, larger than any
/// valid one, or not a complete, valid file for `key`. Never reads more than the limit.
std::optional<Entry> read_cache_file(const std::filesystem::path& path, const tiles::TileKey& key,
                                     std::size_t max_tile_bytes) {
  std::error_code ec;
  const std::uintmax_t size = std::filesystem::file_size(path, ec);
  if (ec || (size > kMaxTileCacheHeaderBytes && size - kMaxTileCacheHeaderBytes > max_tile_bytes)) {
    return std::nullopt;
  }
  std::ifstream in(path, std::ios::binary);
  if (!in) return std::nullopt;
  std::string bytes(static_cast<std::size_t>(size), '\0');
  in.read(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  bytes.resize(static_cast<std::size_t>(in.gcount()));  // shorter if it shrank meanwhile
  TileCacheDecodeResult r = decode_tile_cache_file(bytes, key, max_tile_bytes);
  if (!r.ok()) return std::nullopt;
  Entry e;
  e.tile = std::move(r.tile);
  e.payload = std::move(r.record.payload);
  e.http_status = r.record.http_status;
  e.etag = std::move(r.record.etag);
  e.header_version = r.record.header_version;
  e.fetched_unix_s = r.record.fetched_unix_s;
  return e;
}

/// Atomic write: temporary file in the same directory, then rename. False (nothing
/// written) when the entry cannot be stored or the file system fails.
bool write_cache_file(const std::filesystem::path& path, const tiles::TileKey& key,
                      const Entry& e) {
  std::string bytes;
  try {
    bytes = encode_tile_cache_file(
        {e.http_status, e.etag, e.header_version, e.fetched_unix_s, e.payload}, key);
  } catch (const ValidationError&) {
    return false;
  }
  std::error_code ec;
  std::filesystem::create_directories(path.parent_path(), ec);
  if (ec) return false;
  std::ostringstream tmp_name;
  tmp_name << path.filename().string() << ".tmp." << std::this_thread::get_id();
  const std::filesystem::path tmp = path.parent_path() / tmp_name.str();
  {
    std::ofstream out(tmp, std::ios::binary | std::ios::trunc);
    if (!out) return false;
    out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
    out.flush();
    if (!out) {
      std::filesystem::remove(tmp, ec);
      return false;
    }
  }
  std::filesystem::rename(tmp, path, ec);
  if (ec) {
    std::filesystem::remove(tmp, ec);
    return false;
  }
  return true;
}

}  // namespace

struct TileFetcher::Impl {
  explicit Impl(TileFetcherConfig c) : cfg(std::move(c)) {
    if (!cfg.publication_public_key.empty()) {
      public_pem = util::read_file_bytes(cfg.publication_public_key);
      (void)util::ed25519_key_id(public_pem);  // ValidationError unless an Ed25519 key
      // "scheme://host[:port]/path" -> the client's origin and the publication's path.
      const auto scheme = cfg.server_url.find("://");
      const auto slash =
          scheme == std::string::npos ? std::string::npos : cfg.server_url.find('/', scheme + 3);
      origin = slash == std::string::npos ? cfg.server_url : cfg.server_url.substr(0, slash);
      if (slash != std::string::npos) prefix = cfg.server_url.substr(slash);
      while (!prefix.empty() && prefix.back() == '/') prefix.pop_back();
    }
    if (!cfg.cache_dir.empty()) {
      std::error_code ec;
      std::filesystem::create_directories(cfg.cache_dir, ec);
      if (ec) throw IoError("tile cache directory " + cfg.cache_dir.string() + ": " + ec.message());
    }
    worker = std::thread([this] { run(); });
  }

  ~Impl() {
    {
      std::lock_guard lock(mutex);
      stopping = true;
    }
    cv.notify_all();
    if (worker.joinable()) worker.join();
  }

  // ---- state (guarded by mutex)
  TileFetcherConfig cfg;
  mutable std::mutex mutex;
  std::condition_variable cv;       ///< worker wake-up
  std::condition_variable changed;  ///< an entry or the queue changed (waiters)
  std::map<tiles::TileKey, Entry> entries;
  std::map<tiles::TileKey, Job> jobs;
  bool in_flight = false;
  bool stopping = false;
  std::uint64_t use_tick = 0;
  std::uint64_t job_order = 0;
  SteadyClock::time_point offline_until{};
  double offline_backoff_s = 0.0;
  TileFetcherStats stats;
  std::thread worker;
  // ---- signed static publication (publication_public_key set)
  std::string public_pem;
  std::string origin;  ///< scheme://host[:port] of server_url
  std::string prefix;  ///< its path, without a trailing '/'
  struct Publication {
    std::string dir;
    std::int64_t map_version = 0;
    tiles::PublishedLayer loc;  ///< the localization layer
    std::map<tiles::TileKey, const tiles::PublishedTile*> index;
  };
  std::shared_ptr<const Publication> publication;
  SteadyClock::time_point publication_checked{};

  [[nodiscard]] bool is_stale(const Entry& e) const {
    return e.stale || unix_now_s() - e.fetched_unix_s > cfg.revalidate_after_s;
  }

  /// Queues a key (keeps the more urgent priority / earlier due time).
  void enqueue_locked(const tiles::TileKey& key, int priority, SteadyClock::time_point due) {
    auto [it, inserted] = jobs.try_emplace(key);
    if (inserted) {
      it->second = {priority, due, 0, job_order++};
    } else {
      it->second.priority = std::min(it->second.priority, priority);
      if (it->second.attempts == 0) it->second.due = std::min(it->second.due, due);
    }
    cv.notify_one();
  }

  void evict_locked() {
    while (entries.size() > cfg.memory_capacity_tiles) {
      auto victim = entries.begin();
      for (auto it = entries.begin(); it != entries.end(); ++it) {
        if (it->second.last_used < victim->second.last_used) victim = it;
      }
      entries.erase(victim);
    }
  }

  void note_version_locked(std::uint64_t v) {
    if (v > stats.map_version) {
      // A newer map was published: everything cached may be outdated.
      if (stats.map_version != 0) {
        for (auto& [k, e] : entries) e.stale = true;
      }
      stats.map_version = v;
    }
  }

  void run() {
    std::unique_lock lock(mutex);
    std::optional<httplib::Client> client;
    while (!stopping) {
      // Next due job: lowest priority value, then FIFO.
      const auto now = SteadyClock::now();
      auto pick = jobs.end();
      SteadyClock::time_point earliest = SteadyClock::time_point::max();
      for (auto it = jobs.begin(); it != jobs.end(); ++it) {
        if (it->second.due > now) {
          earliest = std::min(earliest, it->second.due);
          continue;
        }
        if (pick == jobs.end() || it->second.priority < pick->second.priority ||
            (it->second.priority == pick->second.priority &&
             it->second.order < pick->second.order)) {
          pick = it;
        }
      }
      if (pick == jobs.end()) {
        changed.notify_all();
        if (earliest == SteadyClock::time_point::max()) {
          cv.wait(lock);
        } else {
          cv.wait_until(lock, earliest);
        }
        continue;
      }
      const tiles::TileKey key = pick->first;
      Job job = pick->second;
      jobs.erase(pick);
      in_flight = true;
      const double cpu0 = util::thread_cpu_s();
      process_locked(lock, key, job, client);
      stats.worker_cpu_s += util::thread_cpu_s() - cpu0;
      in_flight = false;
      changed.notify_all();
    }
  }

  /// Handles one job; releases the lock around disk and network I/O.
  void process_locked(std::unique_lock<std::mutex>& lock, const tiles::TileKey& key, Job job,
                      std::optional<httplib::Client>& client) {
    // 1. Disk cache.
    if (!entries.contains(key) && !cfg.cache_dir.empty()) {
      lock.unlock();
      auto e = read_cache_file(cache_path(cfg.cache_dir, key), key, cfg.max_tile_bytes);
      lock.lock();
      if (e && !entries.contains(key)) {
        e->last_used = ++use_tick;
        // A copy from a version older than the newest seen must be revalidated.
        if (e->header_version < stats.map_version) e->stale = true;
        entries.emplace(key, std::move(*e));
        ++stats.disk_loads;
        evict_locked();
        changed.notify_all();
      }
    }
    // 2. Server, when needed and allowed.
    const auto it = entries.find(key);
    const bool have = it != entries.end();
    if (cfg.server_url.empty()) return;
    if (have && !is_stale(it->second)) return;
    const auto now = SteadyClock::now();
    if (now < offline_until) {
      // Unreachable: serve the cached copy; keep trying for missing tiles.
      if (!have) enqueue_locked(key, job.priority, offline_until);
      return;
    }
    const std::string etag = have && it->second.http_status == 200 ? it->second.etag : "";
    lock.unlock();
    if (!client) {
      client.emplace(public_pem.empty() ? cfg.server_url : origin);
      const auto us = [](double s) { return static_cast<time_t>(s * 1e6); };
      client->set_connection_timeout(0, us(cfg.connect_timeout_s));
      client->set_read_timeout(0, us(cfg.read_timeout_s));
      client->set_write_timeout(0, us(cfg.read_timeout_s));
      client->set_keep_alive(true);
      if (cfg.server_url.starts_with("https://")) {
        client->enable_server_certificate_verification(true);
        if (!cfg.ca_file.empty()) client->set_ca_cert_path(cfg.ca_file.string());
      }
    }
    if (!public_pem.empty()) return process_static(lock, key, job, *client, have);
    httplib::Headers headers;
    if (!etag.empty()) headers.emplace("If-None-Match", etag);
    std::string path = "/v1/tiles/" + tiles::to_string(key);
    if (!cfg.query.empty()) path += "?" + cfg.query;
    std::string body;
    bool over_limit = false;
    const auto deadline =
        SteadyClock::now() + std::chrono::duration_cast<SteadyClock::duration>(
                                 std::chrono::duration<double>(cfg.request_deadline_s));
    const httplib::Result res = client->Get(path, headers, [&](const char* data, std::size_t n) {
      if (body.size() + n > cfg.max_tile_bytes || SteadyClock::now() > deadline) {
        over_limit = true;
        return false;
      }
      body.append(data, n);
      return true;
    });
    lock.lock();
    if (over_limit) {  // too large or too slow: the server misbehaves, retry later
      ++stats.server_errors;
      lock.unlock();
      client.reset();
      lock.lock();
      retry_locked(key, job);
      return;
    }
    if (!res) {
      note_transport_error_locked(key, have, job);
      lock.unlock();
      client.reset();  // a fresh connection next time
      lock.lock();
      return;
    }
    stats.server_reachable = true;
    offline_backoff_s = 0.0;
    offline_until = {};
    std::uint64_t header_version = 0;
    if (res->has_header("X-Polmap-Map-Version")) {
      // Only a plain decimal number counts; anything else is ignored.
      const std::string v = res->get_header_value("X-Polmap-Map-Version");
      std::uint64_t parsed = 0;
      const auto [p, ec] = std::from_chars(v.data(), v.data() + v.size(), parsed);
      if (v.size() <= 20 && ec == std::errc{} && p == v.data() + v.size()) header_version = parsed;
      if (header_version != 0) note_version_locked(header_version);
    }
    Entry e;
    e.fetched_unix_s = unix_now_s();
    e.header_version = header_version;
    e.last_used = have ? it->second.last_used : ++use_tick;
    switch (res->status) {
      case 200: {
        bool ok = false;
        try {
          e.tile = tiles::decode_localization_tile(body, cfg.server_url + path);
          ok = e.tile.key == key;  // a tile for another place is not this tile
        } catch (const Error&) {
        }
        if (!ok || res->get_header_value("ETag").size() > 256) {
          ++stats.server_errors;
          retry_locked(key, job);
          return;
        }
        ++stats.responses_200;
        stats.bytes_downloaded += body.size();
        e.http_status = 200;
        e.etag = res->get_header_value("ETag");
        e.payload = std::move(body);
        break;
      }
      case 304: {
        ++stats.responses_304;
        if (!have) {  // cannot happen unless the copy was evicted meanwhile
          enqueue_locked(key, job.priority, SteadyClock::now());
          return;
        }
        it->second.fetched_unix_s = e.fetched_unix_s;
        it->second.stale = false;
        if (header_version != 0) it->second.header_version = header_version;
        if (!cfg.cache_dir.empty()) {
          const Entry copy = it->second;
          lock.unlock();
          // Rewritten to refresh the fetch time in the header.
          write_cache_file(cache_path(cfg.cache_dir, key), key, copy);
          lock.lock();
        }
        changed.notify_all();
        return;
      }
      case 404:
        // Only the server's own "outside the map" answer is remembered; any other 404
        // (a proxy's error page, a wrong URL) is an error, retried later.
        if (res->get_header_value("X-Polmap-Coverage") != "outside") {
          ++stats.server_errors;
          retry_locked(key, job);
          return;
        }
        [[fallthrough]];
      case 204: {
        (res->status == 204 ? stats.responses_204 : stats.responses_404) += 1;
        e.http_status = res->status;
        e.tile = empty_tile(key, header_version);
        break;
      }
      default:
        ++stats.server_errors;
        retry_locked(key, job);
        return;
    }
    entries[key] = e;
    evict_locked();
    changed.notify_all();
    if (!cfg.cache_dir.empty()) {
      lock.unlock();
      write_cache_file(cache_path(cfg.cache_dir, key), key, e);
      lock.lock();
    }
  }

  /// GET with a body cap: the status, or -1 on a transport error, -2 over the cap or the
  /// deadline. Called without the lock.
  int get_capped(httplib::Client& client, const std::string& path, std::size_t cap,
                 std::string& body) const {
    body.clear();
    bool over = false;
    const auto deadline =
        SteadyClock::now() + std::chrono::duration_cast<SteadyClock::duration>(
                                 std::chrono::duration<double>(cfg.request_deadline_s));
    const httplib::Result res = client.Get(path, [&](const char* data, std::size_t n) {
      if (body.size() + n > cap || SteadyClock::now() > deadline) {
        over = true;
        return false;
      }
      body.append(data, n);
      return true;
    });
    if (over) return -2;
    if (!res) return -1;
    return res->status;
  }

  /// The server is unreachable: back off (doubling), and keep a missing tile queued.
  void note_transport_error_locked(const tiles::TileKey& key, bool have, const Job& job) {
    ++stats.transport_errors;
    stats.server_reachable = false;
    offline_backoff_s = offline_backoff_s <= 0.0
                            ? cfg.backoff_initial_s
                            : std::min(cfg.backoff_max_s, 2.0 * offline_backoff_s);
    offline_until = SteadyClock::now() + std::chrono::duration_cast<SteadyClock::duration>(
                                             std::chrono::duration<double>(offline_backoff_s));
    if (!have) enqueue_locked(key, job.priority, offline_until);
  }

  /// Reads latest.json and, when it names another directory, that directory's signed
  /// manifest (class comment). Returns -1 on a transport error, 0 on a rejected or failed
  /// answer (counted), 1 when the publication in use is current. Called without the lock.
  int refresh_publication(httplib::Client& client) {
    std::string body;
    const int st = get_capped(client, prefix + "/latest.json", 4096, body);
    if (st == -1) return -1;
    if (st != 200) return 0;
    tiles::PublicationPointer ptr;
    try {
      ptr = tiles::parse_publication_pointer(body, cfg.server_url + "/latest.json");
    } catch (const Error&) {
      return 0;
    }
    std::shared_ptr<const Publication> cur;
    {
      std::lock_guard g(mutex);
      cur = publication;
    }
    if (cur && cur->dir == ptr.dir) return 1;
    std::string manifest, sig;
    const std::string base = prefix + "/" + ptr.dir + "/";
    int ms = get_capped(client, base + "manifest.json", cfg.max_manifest_bytes, manifest);
    if (ms == -1) return -1;
    const int ss = ms == 200 ? get_capped(client, base + "manifest.sig", 1024, sig) : 0;
    if (ss == -1) return -1;
    auto reject = [&] {
      std::lock_guard g(mutex);
      ++stats.manifest_rejections;
      return 0;
    };
    if (ms != 200 || ss != 200) return reject();
    while (!sig.empty() && (sig.back() == '\n' || sig.back() == '\r')) sig.pop_back();
    // The signature first: only the publisher's bytes are parsed.
    if (util::sha256_hex(manifest) != ptr.manifest_sha256 ||
        !util::ed25519_verify_hex(public_pem, manifest, sig)) {
      return reject();
    }
    auto next = std::make_shared<Publication>();
    try {
      tiles::ManifestLimits lim;
      lim.max_bytes = cfg.max_manifest_bytes;
      lim.max_tile_bytes = cfg.max_tile_bytes;
      tiles::PublicationManifest m =
          tiles::parse_publication_manifest(manifest, lim, cfg.server_url + "/" + base);
      const tiles::PublishedLayer* loc = m.layer("localization");
      if (loc == nullptr || m.map_version != ptr.map_version) return reject();
      next->dir = ptr.dir;
      next->map_version = m.map_version;
      next->loc = *loc;
    } catch (const Error&) {
      return reject();
    }
    for (const auto& t : next->loc.tiles) next->index.emplace(t.key, &t);
    std::lock_guard g(mutex);
    if (publication && next->map_version < publication->map_version) {
      ++stats.manifest_rejections;  // an older map: a stale or hostile mirror
      return 0;
    }
    publication = std::move(next);
    ++stats.manifests_adopted;
    note_version_locked(static_cast<std::uint64_t>(publication->map_version));
    return 1;
  }

  /// One tile from the static publication (lock released on entry, held on return).
  void process_static(std::unique_lock<std::mutex>& lock, const tiles::TileKey& key, Job job,
                      httplib::Client& client, bool have) {
    const bool recheck = SteadyClock::now() - publication_checked >
                         std::chrono::duration_cast<SteadyClock::duration>(
                             std::chrono::duration<double>(cfg.revalidate_after_s));
    if (!publication || recheck) {
      const int r = refresh_publication(client);
      lock.lock();
      if (r == -1) return note_transport_error_locked(key, have, job);
      stats.server_reachable = true;
      offline_backoff_s = 0.0;
      offline_until = {};
      if (r == 1) publication_checked = SteadyClock::now();
      if (!publication) {
        ++stats.server_errors;
        return retry_locked(key, job);
      }
      lock.unlock();
    }
    lock.lock();
    const std::shared_ptr<const Publication> pub = publication;
    const auto it = entries.find(key);
    Entry e;
    e.fetched_unix_s = unix_now_s();
    e.header_version = static_cast<std::uint64_t>(pub->map_version);
    e.last_used = it != entries.end() ? it->second.last_used : ++use_tick;
    const auto listed = pub->index.find(key);
    if (listed == pub->index.end()) {
      // Not in the publication: outside the map.
      ++stats.responses_404;
      e.http_status = 404;
      e.tile = empty_tile(key, e.header_version);
    } else if (it != entries.end() && it->second.http_status == 200 &&
               it->second.etag == listed->second->sha256) {
      // The cached bytes are the listed ones: confirmed without a request.
      ++stats.responses_304;
      it->second.fetched_unix_s = e.fetched_unix_s;
      it->second.stale = false;
      it->second.header_version = e.header_version;
      changed.notify_all();
      return;
    } else {
      const tiles::PublishedTile want = *listed->second;
      const std::string path =
          prefix + "/" + pub->dir + "/" + tiles::published_tile_path(pub->loc, key);
      lock.unlock();
      std::string body;
      const int st =
          get_capped(client, path, std::min<std::size_t>(cfg.max_tile_bytes, want.bytes), body);
      lock.lock();
      if (st == -1) return note_transport_error_locked(key, have, job);
      stats.server_reachable = true;
      if (st != 200) {
        ++stats.server_errors;
        return retry_locked(key, job);
      }
      if (util::sha256_hex(body) != want.sha256) {
        ++stats.hash_mismatches;  // altered on the way: refused
        ++stats.server_errors;
        return retry_locked(key, job);
      }
      try {
        e.tile = tiles::decode_localization_tile(body, cfg.server_url + path);
      } catch (const Error&) {
        ++stats.server_errors;
        return retry_locked(key, job);
      }
      if (e.tile.key != key) {
        ++stats.server_errors;
        return retry_locked(key, job);
      }
      ++stats.responses_200;
      stats.bytes_downloaded += body.size();
      e.http_status = 200;
      e.etag = want.sha256;
      e.payload = std::move(body);
    }
    entries[key] = e;
    evict_locked();
    changed.notify_all();
    if (!cfg.cache_dir.empty()) {
      lock.unlock();
      write_cache_file(cache_path(cfg.cache_dir, key), key, e);
      lock.lock();
    }
  }

  void retry_locked(const tiles::TileKey& key, Job job) {
    ++job.attempts;
    const double delay =
        std::min(cfg.backoff_max_s, cfg.backoff_initial_s * std::pow(2.0, job.attempts - 1));
    job.due = SteadyClock::now() + std::chrono::duration_cast<SteadyClock::duration>(
                                       std::chrono::duration<double>(delay));
    auto [jt, inserted] = jobs.try_emplace(key, job);
    if (!inserted) jt->second.priority = std::min(jt->second.priority, job.priority);
    cv.notify_one();
  }
};

TileFetcher::TileFetcher(TileFetcherConfig cfg) : impl_(std::make_unique<Impl>(std::move(cfg))) {}
TileFetcher::~TileFetcher() = default;

std::optional<tiles::LocalizationTile> TileFetcher::tile(const tiles::TileKey& key) {
  std::lock_guard lock(impl_->mutex);
  auto& I = *impl_;
  const auto it = I.entries.find(key);
  if (it == I.entries.end()) {
    ++I.stats.memory_misses;
    I.enqueue_locked(key, kMissing, SteadyClock::now());
    return std::nullopt;
  }
  ++I.stats.memory_hits;
  it->second.last_used = ++I.use_tick;
  if (!I.cfg.server_url.empty() && I.is_stale(it->second)) {
    I.enqueue_locked(key, kRevalidate, std::max(SteadyClock::now(), I.offline_until));
  }
  return it->second.tile;
}

void TileFetcher::prefetch(std::span<const tiles::TileKey> keys) {
  std::lock_guard lock(impl_->mutex);
  for (const auto& k : keys) {
    const auto it = impl_->entries.find(k);
    if (it == impl_->entries.end()) {
      impl_->enqueue_locked(k, kPrefetch, SteadyClock::now());
    } else if (!impl_->cfg.server_url.empty() && impl_->is_stale(it->second)) {
      impl_->enqueue_locked(k, kRevalidate, std::max(SteadyClock::now(), impl_->offline_until));
    }
  }
}

bool TileFetcher::wait_for(std::span<const tiles::TileKey> keys, double timeout_s) {
  const auto deadline = SteadyClock::now() + std::chrono::duration_cast<SteadyClock::duration>(
                                                 std::chrono::duration<double>(timeout_s));
  std::unique_lock lock(impl_->mutex);
  for (const auto& k : keys) {
    if (!impl_->entries.contains(k)) impl_->enqueue_locked(k, kMissing, SteadyClock::now());
  }
  return impl_->changed.wait_until(lock, deadline, [&] {
    return std::all_of(keys.begin(), keys.end(),
                       [&](const auto& k) { return impl_->entries.contains(k); });
  });
}

bool TileFetcher::wait_idle(double timeout_s) {
  const auto deadline = SteadyClock::now() + std::chrono::duration_cast<SteadyClock::duration>(
                                                 std::chrono::duration<double>(timeout_s));
  std::unique_lock lock(impl_->mutex);
  impl_->cv.notify_one();
  return impl_->changed.wait_until(lock, deadline, [&] {
    if (impl_->in_flight) return false;
    const auto now = SteadyClock::now();
    return std::none_of(impl_->jobs.begin(), impl_->jobs.end(),
                        [&](const auto& kv) { return kv.second.due <= now; });
  });
}

void TileFetcher::invalidate_all() {
  std::lock_guard lock(impl_->mutex);
  for (auto& [k, e] : impl_->entries) e.stale = true;
}

TileFetcherStats TileFetcher::stats() const {
  std::lock_guard lock(impl_->mutex);
  TileFetcherStats s = impl_->stats;
  s.queued = impl_->jobs.size();
  return s;
}

const TileFetcherConfig& TileFetcher::config() const { return impl_->cfg; }

}  // namespace polmap::loc
