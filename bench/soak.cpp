// Soak load driver (run by tools/soak against a real `polmap serve` on loopback):
//   bench_soak --url URL --key KEY --packages DIR --pid PID [--duration-s 3600]
//              [--upload-every-s 30] [--build-every-s 120] [--readers 2] [--rate 40]
//              [--sample-every-s 10] [--report FILE]
// Mixed load for the whole duration: localization tiles, MVT tiles, TileJSON and
// conditional requests (If-None-Match) from `readers` threads at `rate` requests/s in all;
// an upload every upload-every-s (DIR/*.tar round robin; once all are stored, each upload
// first deletes the drive it re-sends, so every upload is a real ingest); a map build every
// build-every-s, polled until it ends. The server's resident memory and file descriptors
// (/proc/PID) are sampled every sample-every-s. At the end it prints and writes a JSON
// report and exits 1 unless: no 5xx, the resident-memory peak of the last 10 minutes is
// < 5 % above the peak of the 10 minutes after half time, and the non-socket descriptors'
// peak of the last 10 minutes is not above that of the 10 minutes after half time. `bench_soak
// --analyze REPORT` recomputes the memory verdict.
#include <httplib.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <mutex>
#include <nlohmann/json.hpp>
#include <random>
#include <thread>

#include "polmap/mapping_service/ustar.hpp"
#include "polmap/tiles/tile_key.hpp"
#include "polmap/util/file.hpp"

namespace fs = std::filesystem;
using namespace polmap;
using Clock = std::chrono::steady_clock;

namespace {

struct Sample {
  double t_s;
  long rss_kib;
  int file_fds;
  int socket_fds;
};

struct Stats {
  std::mutex mu;
  std::map<std::string, std::map<int, long>> status;  ///< request class -> status -> count
  std::vector<double> tile_ms_idle, tile_ms_building;
  std::vector<std::string> errors;  ///< first few 5xx / transport failures
  std::vector<double> build_s;
  std::vector<Sample> samples;
  void count(const std::string& what, int code, const std::string& detail) {
    std::lock_guard lock(mu);
    ++status[what][code];
    if ((code >= 500 || code < 0) && errors.size() < 20) {
      errors.push_back(what + " " + std::to_string(code) + " " + detail);
    }
  }
};

long rss_kib(int pid) {
  std::ifstream in("/proc/" + std::to_string(pid) + "/status");
  std::string line;
  while (std::getline(in, line)) {
    if (line.starts_with("VmRSS:")) return std::stol(line.substr(6));
  }
  return -1;
}

std::pair<int, int> fds(int pid) {
  int files = 0, sockets = 0;
  std::error_code ec;
  for (const auto& e : fs::directory_iterator("/proc/" + std::to_string(pid) + "/fd", ec)) {
    const auto target = fs::read_symlink(e.path(), ec).string();
    (target.starts_with("socket:") ? sockets : files)++;
  }
  return {files, sockets};
}

double percentile(std::vector<double> v, double p) {
  if (v.empty()) return 0.0;
  std::sort(v.begin(), v.end());
  const auto i = static_cast<std::size_t>(std::min<double>(v.size() - 1, p * (v.size() - 1)));
  return v[i];
}

/// Memory and descriptors over the last half. A build's allocations make resident memory
/// a sawtooth, so growth compares peaks: the highest sample of the first `window_s` of the
/// last half against the highest of the last `window_s` (each window spans several builds).
/// Descriptors likewise: a build or an upload holds files while it runs and the store opens
/// pooled SQLite connections on demand (at most its idle bound), so a leak shows as a late
/// peak above the early one, not as any change.
struct MemoryVerdict {
  bool complete = false;
  long peak_early_kib = 0, peak_late_kib = 0;
  double growth = 0.0;
  int min_files = 0, max_files = 0, max_sockets = 0;
  int files_peak_early = 0, files_peak_late = 0;  ///< same windows as the memory peaks
};

MemoryVerdict memory_verdict(const std::vector<Sample>& samples, double duration_s,
                             double sample_every_s) {
  MemoryVerdict v;
  const double half = 0.5 * duration_s;
  const double window_s = std::min(600.0, 0.25 * duration_s);
  v.min_files = 1 << 30;
  bool any = false;
  for (const auto& s : samples) {
    if (s.t_s < half) continue;
    any = true;
    if (s.t_s < half + window_s) {
      v.peak_early_kib = std::max(v.peak_early_kib, s.rss_kib);
      v.files_peak_early = std::max(v.files_peak_early, s.file_fds);
    }
    if (s.t_s >= duration_s - window_s) {
      v.peak_late_kib = std::max(v.peak_late_kib, s.rss_kib);
      v.files_peak_late = std::max(v.files_peak_late, s.file_fds);
    }
    v.min_files = std::min(v.min_files, s.file_fds);
    v.max_files = std::max(v.max_files, s.file_fds);
    v.max_sockets = std::max(v.max_sockets, s.socket_fds);
  }
  v.complete = any && v.peak_early_kib > 0 && v.peak_late_kib > 0 &&
               samples.back().t_s >= duration_s - 2 * sample_every_s;
  if (v.complete) v.growth = static_cast<double>(v.peak_late_kib) / v.peak_early_kib - 1.0;
  return v;
}

std::string manifest_drive_id(const std::string& tar) {
  for (const auto& m : mapping::read_ustar_views(tar, "package")) {
    if (m.name == "manifest.json") return nlohmann::json::parse(m.data).at("drive_id");
  }
  return {};
}

nlohmann::json origin_of(const std::string& tar) {
  for (const auto& m : mapping::read_ustar_views(tar, "package")) {
    if (m.name == "manifest.json") return nlohmann::json::parse(m.data).at("origin");
  }
  return {};
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"polmap soak load driver"};
  std::string url, key, packages, report;
  int pid = 0, readers = 2;
  double duration_s = 3600, upload_every_s = 30, build_every_s = 120, rate = 40,
         sample_every_s = 10;
  app.add_option("--url", url)->required();
  app.add_option("--key", key, "operator key")->required();
  app.add_option("--packages", packages, "directory of drive package archives (*.tar)")->required();
  app.add_option("--pid", pid, "server process to sample")->required();
  app.add_option("--duration-s", duration_s)->capture_default_str();
  app.add_option("--upload-every-s", upload_every_s)->capture_default_str();
  app.add_option("--build-every-s", build_every_s)->capture_default_str();
  app.add_option("--readers", readers)->capture_default_str();
  app.add_option("--rate", rate, "read requests per second, all readers")->capture_default_str();
  app.add_option("--sample-every-s", sample_every_s)->capture_default_str();
  app.add_option("--report", report, "JSON report file");
  std::string analyze;
  app.add_option("--analyze", analyze,
                 "only recompute the memory and descriptor verdict of an existing report");
  if (argc > 1 && std::string(argv[1]) == "--analyze" && argc == 3) {
    std::ifstream in(argv[2]);
    const auto r = nlohmann::json::parse(in);
    std::vector<Sample> samples;
    for (const auto& x : r.at("samples")) {
      samples.push_back({x[0].get<double>(), x[1].get<long>(), x[2].get<int>(), x[3].get<int>()});
    }
    const MemoryVerdict v = memory_verdict(samples, r.at("duration_s"), 10.0);
    const bool ok = v.complete && v.growth < 0.05 && v.files_peak_late <= v.files_peak_early;
    std::printf(
        "%s: RSS peak %.1f MiB early in the last half, %.1f MiB at its end (growth %.2f "
        "%%); non-socket fds %d..%d; %s\n",
        argv[2], v.peak_early_kib / 1024.0, v.peak_late_kib / 1024.0, 100 * v.growth, v.min_files,
        v.max_files, ok ? "PASS" : "FAIL");
    return ok ? 0 : 1;
  }
  CLI11_PARSE(app, argc, argv);

  std::vector<std::string> tars;
  for (const auto& e : fs::directory_iterator(packages)) {
    if (e.path().extension() == ".tar") tars.push_back(util::read_file_bytes(e.path()));
  }
  if (tars.empty()) {
    std::fprintf(stderr, "bench_soak: no *.tar in %s\n", packages.c_str());
    return 2;
  }
  // Tiles to read: the 5x5 z16 tiles around each drive origin, their MVT z14..16 parents.
  std::vector<std::string> tile_paths, mvt_paths;
  for (const auto& t : tars) {
    const auto o = origin_of(t);
    const auto c = tiles::tile_at(o.at("lat_deg"), o.at("lon_deg"), tiles::kLocalizationZoom);
    for (int dx = -2; dx <= 2; ++dx) {
      for (int dy = -2; dy <= 2; ++dy) {
        const auto k = tiles::neighbour(c, dx, dy);
        if (!k) continue;
        tile_paths.push_back("/v1/tiles/" + tiles::to_string(*k));
        mvt_paths.push_back("/v1/mvt/" + tiles::to_string(*k) + ".mvt");
        const auto p = tiles::parent(*k);
        mvt_paths.push_back("/v1/mvt/" + tiles::to_string(p) + ".mvt");
        mvt_paths.push_back("/v1/mvt/" + tiles::to_string(tiles::parent(p)) + ".mvt");
      }
    }
  }
  const httplib::Headers auth{{"Authorization", "Bearer " + key}};
  Stats stats;
  std::atomic<bool> building{false}, done{false};
  const auto t0 = Clock::now();
  const auto elapsed_s = [&] { return std::chrono::duration<double>(Clock::now() - t0).count(); };
  const auto client = [&] {
    auto c = std::make_unique<httplib::Client>(url);
    c->set_connection_timeout(5);
    c->set_read_timeout(60);
    c->set_keep_alive(true);
    return c;
  };

  std::vector<std::thread> threads;
  for (int r = 0; r < readers; ++r) {
    threads.emplace_back([&, r] {
      auto c = client();
      std::mt19937 rng(static_cast<unsigned>(r + 1));
      std::map<std::string, std::string> etags;
      const auto period = std::chrono::duration<double>(readers / std::max(rate, 0.1));
      auto next = Clock::now();
      while (!done) {
        next += std::chrono::duration_cast<Clock::duration>(period);
        std::this_thread::sleep_until(next);
        const int kind = static_cast<int>(rng() % 10);
        std::string what, path;
        httplib::Headers h;
        if (kind < 5) {
          what = "tile";
          path = tile_paths[rng() % tile_paths.size()];
        } else if (kind < 8) {
          what = "mvt";
          path = mvt_paths[rng() % mvt_paths.size()];
        } else if (kind < 9) {
          what = "conditional";
          path = tile_paths[rng() % tile_paths.size()];
          if (etags.contains(path)) h.emplace("If-None-Match", etags[path]);
        } else {
          what = "tilejson";
          path = "/v1/tilejson.json";
        }
        const bool during_build = building;
        const auto s = Clock::now();
        auto res = c->Get(path, h);
        const double ms = std::chrono::duration<double, std::milli>(Clock::now() - s).count();
        if (!res) {
          stats.count(what, -1, path + ": " + httplib::to_string(res.error()));
          c = client();
          continue;
        }
        stats.count(what, res->status, path);
        if (res->has_header("ETag")) etags[path] = res->get_header_value("ETag");
        if (what == "tile" || what == "mvt") {
          std::lock_guard lock(stats.mu);
          (during_build ? stats.tile_ms_building : stats.tile_ms_idle).push_back(ms);
        }
      }
    });
  }
  threads.emplace_back([&] {  // uploads (and the deletes that make each a real ingest)
    auto c = client();
    std::vector<std::string> ids(tars.size());
    for (std::size_t k = 0; !done; ++k) {
      const std::size_t i = k % tars.size();
      if (k >= tars.size()) {
        if (ids[i].empty()) ids[i] = manifest_drive_id(tars[i]);
        auto d = c->Delete("/v1/drives/" + ids[i], auth);
        stats.count("delete", d ? d->status : -1, ids[i]);
        if (!d) c = client();
      }
      auto res = c->Post("/v1/drives", auth, tars[i], "application/x-tar");
      stats.count("upload", res ? res->status : -1, "drive " + std::to_string(i));
      if (!res) c = client();
      const auto until = t0 + std::chrono::duration_cast<Clock::duration>(
                                  std::chrono::duration<double>(upload_every_s * (k + 1)));
      while (!done && Clock::now() < until)
        std::this_thread::sleep_for(std::chrono::milliseconds(200));
    }
  });
  threads.emplace_back([&] {  // map builds, polled to the end
    auto c = client();
    for (std::size_t k = 1; !done; ++k) {
      const auto until = t0 + std::chrono::duration_cast<Clock::duration>(
                                  std::chrono::duration<double>(build_every_s * k));
      while (!done && Clock::now() < until)
        std::this_thread::sleep_for(std::chrono::milliseconds(200));
      if (done) break;
      const auto s = Clock::now();
      auto res = c->Post("/v1/maps", auth, "{}", "application/json");
      stats.count("build", res ? res->status : -1, "POST /v1/maps");
      if (!res || res->status != 202) {
        if (!res) c = client();
        continue;
      }
      const auto version = nlohmann::json::parse(res->body).at("version").get<std::int64_t>();
      building = true;
      for (;;) {
        std::this_thread::sleep_for(std::chrono::milliseconds(500));
        auto v = c->Get("/v1/maps/" + std::to_string(version));
        if (!v) {
          c = client();
          continue;
        }
        stats.count("build_status", v->status, "GET /v1/maps/" + std::to_string(version));
        if (v->status != 200 || nlohmann::json::parse(v->body).value("status", "") != "building") {
          break;
        }
      }
      building = false;
      std::lock_guard lock(stats.mu);
      stats.build_s.push_back(std::chrono::duration<double>(Clock::now() - s).count());
    }
  });
  // Sampling and progress on this thread.
  for (double next = 0.0; elapsed_s() < duration_s; next += sample_every_s) {
    while (elapsed_s() < next) std::this_thread::sleep_for(std::chrono::milliseconds(100));
    const auto [files, sockets] = fds(pid);
    const long rss = rss_kib(pid);
    if (rss < 0) {
      std::fprintf(stderr, "bench_soak: server process %d is gone\n", pid);
      break;
    }
    std::lock_guard lock(stats.mu);
    stats.samples.push_back({elapsed_s(), rss, files, sockets});
    long requests = 0;
    for (const auto& [w, m] : stats.status) {
      for (const auto& [code, n] : m) requests += n;
    }
    std::fprintf(stderr, "\rbench_soak: %5.0f/%.0f s  %ld requests  RSS %ld MiB  fds %d+%d  ",
                 elapsed_s(), duration_s, requests, rss / 1024, files, sockets);
  }
  std::fprintf(stderr, "\n");
  done = true;
  for (auto& t : threads) t.join();

  // Verdict over the last half.
  nlohmann::json j;
  long fivexx = 0, transport = 0;
  for (const auto& [w, m] : stats.status) {
    for (const auto& [code, n] : m) {
      j["status"][w][std::to_string(code)] = n;
      if (code >= 500) fivexx += n;
      if (code < 0) transport += n;
    }
  }
  const MemoryVerdict mv = memory_verdict(stats.samples, duration_s, sample_every_s);
  const bool complete = mv.complete;
  const double growth = mv.growth;
  const int min_files = mv.min_files, max_files = mv.max_files, max_sockets = mv.max_sockets;
  j["duration_s"] = duration_s;
  j["requests_5xx"] = fivexx;
  j["transport_failures"] = transport;
  j["errors"] = stats.errors;
  j["rss_mib_peak_early_last_half"] = mv.peak_early_kib / 1024.0;
  j["rss_mib_peak_late_last_half"] = mv.peak_late_kib / 1024.0;
  j["rss_growth_last_half"] = growth;
  j["file_fds_last_half"] = {min_files, max_files};
  j["socket_fds_max_last_half"] = max_sockets;
  j["tile_ms"]["idle"] = {{"n", stats.tile_ms_idle.size()},
                          {"p50", percentile(stats.tile_ms_idle, 0.5)},
                          {"p99", percentile(stats.tile_ms_idle, 0.99)}};
  j["tile_ms"]["building"] = {{"n", stats.tile_ms_building.size()},
                              {"p50", percentile(stats.tile_ms_building, 0.5)},
                              {"p99", percentile(stats.tile_ms_building, 0.99)}};
  j["builds"] = {{"n", stats.build_s.size()},
                 {"p50_s", percentile(stats.build_s, 0.5)},
                 {"max_s", percentile(stats.build_s, 1.0)}};
  for (const auto& s : stats.samples)
    j["samples"].push_back({s.t_s, s.rss_kib, s.file_fds, s.socket_fds});
  const bool ok =
      complete && fivexx == 0 && transport == 0 && growth < 0.05 && min_files == max_files;
  j["pass"] = ok;
  if (!report.empty()) std::ofstream(report) << j.dump(2) << "\n";
  std::printf(
      "soak %.0f s: %s\n  5xx %ld, transport failures %ld\n  RSS peak %.1f MiB early in the last "
      "half, %.1f MiB at its end (growth %.2f %%)\n  file descriptors (non-socket) last half "
      "%d..%d, sockets <= "
      "%d\n  tile p50/p99 %.1f/%.1f ms idle (n %zu), %.1f/%.1f ms during builds (n %zu)\n  "
      "builds %zu, median %.1f s\n",
      duration_s, ok ? "PASS" : "FAIL", fivexx, transport, mv.peak_early_kib / 1024.0,
      mv.peak_late_kib / 1024.0, 100 * growth, min_files, max_files, max_sockets,
      percentile(stats.tile_ms_idle, 0.5), percentile(stats.tile_ms_idle, 0.99),
      stats.tile_ms_idle.size(), percentile(stats.tile_ms_building, 0.5),
      percentile(stats.tile_ms_building, 0.99), stats.tile_ms_building.size(), stats.build_s.size(),
      percentile(stats.build_s, 0.5));
  for (const auto& e : stats.errors) std::printf("  error: %s\n", e.c_str());
  return ok ? 0 : 1;
}
