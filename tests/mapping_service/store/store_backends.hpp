#pragma once
// The store backends under one contract: value-parameterized tests (TEST_P on
// StoreContract or a fixture derived from it) run once on a SqliteMapStore in a temp dir and
// once on a PostgresMapStore in a fresh database of this test binary's throw-away cluster.
//
// The cluster: `tools/postgres start --fast $(mktemp -d)`, started once per test process
// when the first PostgreSQL test is about to run (the environment's SetUp, when the selected
// tests include one; --gtest_list_tests, as test discovery runs it, calls no SetUp and
// starts nothing), stopped in the environment's TearDown, and by a watchdog process should
// this process die without it. If it cannot start, every PostgreSQL test fails with the
// script's output: the tests never skip. Each test gets its own database (CREATE DATABASE
// test_<pid>_<n> from the cluster's postgis-enabled database "polmap" as template, then
// CREATE EXTENSION IF NOT EXISTS postgis) and its own package directory.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <libpq-fe.h>
#include <signal.h>
#include <stdlib.h>
#include <sys/wait.h>
#include <unistd.h>

#include <array>
#include <atomic>
#include <cstdio>
#include <filesystem>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <string_view>

#include "polmap/mapping_service/postgres_store.hpp"
#include "polmap/mapping_service/sqlite_store.hpp"
#include "test_dir.hpp"

namespace polmap::mapping::testing {

/// The throw-away PostgreSQL cluster of this test process.
class PostgresCluster {
 public:
  static PostgresCluster& instance() {
    static PostgresCluster c;
    return c;
  }

  /// Starts the cluster unless it runs (or failed to start: the same error again).
  /// Throws std::runtime_error with the script's output when it cannot start.
  void ensure_started() {
    std::lock_guard lock(mu_);
    if (!url_.empty()) return;
    if (!error_.empty()) throw std::runtime_error(error_);
    char templ[] = "/tmp/polmap-test-pg.XXXXXX";
    if (mkdtemp(templ) == nullptr) {
      error_ = "mkdtemp /tmp/polmap-test-pg.XXXXXX failed";
      throw std::runtime_error(error_);
    }
    dir_ = templ;
    const std::string script = std::string(POLMAP_SOURCE_DIR) + "/tools/postgres";
    std::string out;
    const int rc = run_capture("'" + script + "' start --fast '" + dir_ + "' 2>&1", out);
    std::string last;
    for (std::size_t pos = 0; pos < out.size();) {
      const std::size_t eol = std::min(out.find('\n', pos), out.size());
      if (eol > pos) last = out.substr(pos, eol - pos);
      pos = eol + 1;
    }
    if (rc != 0 || !last.starts_with("postgresql://")) {
      error_ = "tools/postgres start --fast " + dir_ + " failed (exit " + std::to_string(rc) +
               "):\n" + out;
      stop_locked();
      throw std::runtime_error(error_);
    }
    url_ = last;
    start_watchdog();
  }

  /// Stops the cluster and removes its directory (no-op if it never started).
  void stop() {
    std::lock_guard lock(mu_);
    stop_locked();
  }

  /// A new database with PostGIS; returns its URL.
  std::string create_database() {
    ensure_started();
    static std::atomic<int> counter{0};
    const std::string name = "test_" + std::to_string(::getpid()) + "_" + std::to_string(++counter);
    admin("postgres", "CREATE DATABASE " + name + " TEMPLATE polmap");
    const std::string url = url_for(name);
    admin(name, "CREATE EXTENSION IF NOT EXISTS postgis");
    return url;
  }

  /// Runs SQL on a database of the cluster (tests that look at the tables).
  void exec(const std::string& db_url, const std::string& sql) {
    PGconn* c = PQconnectdb(db_url.c_str());
    PQsetNoticeProcessor(
        c, [](void*, const char*) {}, nullptr);
    const bool ok = PQstatus(c) == CONNECTION_OK;
    std::string err = ok ? "" : PQerrorMessage(c);
    if (ok) {
      PGresult* r = PQexec(c, sql.c_str());
      const auto st = PQresultStatus(r);
      if (st != PGRES_COMMAND_OK && st != PGRES_TUPLES_OK) err = PQerrorMessage(c);
      PQclear(r);
    }
    PQfinish(c);
    if (!err.empty()) throw std::runtime_error("postgres test helper: " + sql + ": " + err);
  }

  /// The first column of the first row of a query, as text.
  std::string scalar(const std::string& db_url, const std::string& sql) {
    PGconn* c = PQconnectdb(db_url.c_str());
    std::string out, err;
    if (PQstatus(c) != CONNECTION_OK) {
      err = PQerrorMessage(c);
    } else {
      PGresult* r = PQexec(c, sql.c_str());
      if (PQresultStatus(r) != PGRES_TUPLES_OK) {
        err = PQerrorMessage(c);
      } else if (PQntuples(r) > 0) {
        out = PQgetvalue(r, 0, 0);
      }
      PQclear(r);
    }
    PQfinish(c);
    if (!err.empty()) throw std::runtime_error("postgres test helper: " + sql + ": " + err);
    return out;
  }

  [[nodiscard]] std::string url_for(const std::string& db) const {
    return url_.substr(0, url_.rfind('/') + 1) + db;
  }

 private:
  PostgresCluster() = default;
  ~PostgresCluster() { stop(); }

  static int run_capture(const std::string& cmd, std::string& out) {
    FILE* p = ::popen(cmd.c_str(), "r");
    if (p == nullptr) return -1;
    std::array<char, 4096> buf{};
    std::size_t n = 0;
    while ((n = std::fread(buf.data(), 1, buf.size(), p)) > 0) out.append(buf.data(), n);
    const int st = ::pclose(p);
    return WIFEXITED(st) ? WEXITSTATUS(st) : -1;
  }

  void admin(const std::string& db, const std::string& sql) { exec(url_for(db), sql); }

  void stop_locked() {
    if (dir_.empty()) return;
    std::string out;
    (void)run_capture(
        "'" + std::string(POLMAP_SOURCE_DIR) + "/tools/postgres' stop '" + dir_ + "' 2>&1", out);
    std::error_code ec;
    std::filesystem::remove_all(dir_, ec);
    dir_.clear();
    url_.clear();
  }

  /// A detached shell that stops the cluster once this process is gone, however it ended
  /// (a crash, a ctest timeout's kill). Its output goes nowhere, so ctest does not wait.
  void start_watchdog() {
    const std::string cmd = "while kill -0 " + std::to_string(::getpid()) +
                            " 2>/dev/null; do sleep 1; done; '" + std::string(POLMAP_SOURCE_DIR) +
                            "/tools/postgres' stop '" + dir_ + "' >/dev/null 2>&1; rm -rf '" +
                            dir_ + "'";
    const pid_t pid = ::fork();
    if (pid != 0) return;  // the parent (or a failed fork: no watchdog)
    ::setsid();
    for (int fd = 0; fd < 1024; ++fd) ::close(fd);
    (void)::open("/dev/null", O_RDWR);
    (void)::dup(0);
    (void)::dup(0);
    ::execl("/bin/sh", "sh", "-c", cmd.c_str(), static_cast<char*>(nullptr));
    ::_exit(127);
  }

  std::mutex mu_;
  std::string dir_;
  std::string url_;
  std::string error_;
};

/// Starts the cluster before the first test if a PostgreSQL test is selected; stops it
/// after the last.
class PostgresEnvironment : public ::testing::Environment {
 public:
  void SetUp() override {
    const auto* unit = ::testing::UnitTest::GetInstance();
    for (int i = 0; i < unit->total_test_suite_count(); ++i) {
      const auto* suite = unit->GetTestSuite(i);
      for (int j = 0; j < suite->total_test_count(); ++j) {
        const auto* t = suite->GetTestInfo(j);
        if (!t->should_run()) continue;
        if (std::string_view(t->name()).ends_with("/postgres") ||
            std::string_view(suite->name()).starts_with("Postgres")) {
          try {
            PostgresCluster::instance().ensure_started();
          } catch (const std::exception&) {
            // Reported by each PostgreSQL test (ensure_started throws the same error).
          }
          return;
        }
      }
    }
  }
  void TearDown() override { PostgresCluster::instance().stop(); }
};

inline ::testing::Environment* const kPostgresEnvironment =
    ::testing::AddGlobalTestEnvironment(new PostgresEnvironment);

/// What a contract test may set when it opens a store.
struct ContractOpenOptions {
  double orphan_grace_s = 600.0;
  std::function<void(std::string_view)> fault_hook;
};

/// A fixture over one backend ("sqlite" or "postgres"): fresh storage per test; open()
/// gives a new store object on it (a reopen, or a second process / replica).
class StoreContract : public ::testing::TestWithParam<std::string> {
 protected:
  void SetUp() override {
    tmp_ = std::make_unique<polmap::test::TestDir>("store_contract");
    if (postgres()) {
      url_ = PostgresCluster::instance().create_database();
      drive_dir_ = tmp_->path() / "packages";
      upload_dir_ = drive_dir_ / "uploads";
    } else {
      drive_dir_ = tmp_->path() / "map.db.drives";
      upload_dir_ = tmp_->path() / "map.db.uploads";
    }
  }
  void TearDown() override {
    store_.reset();
    tmp_.reset();
  }

  [[nodiscard]] bool postgres() const { return GetParam() == "postgres"; }

  /// A new store object on this test's storage.
  std::unique_ptr<MapStore> open(const ContractOpenOptions& o = {}) const {
    if (postgres()) {
      PostgresStoreOptions p;
      p.conninfo = url_;
      p.package_dir = drive_dir_;
      p.orphan_grace_s = o.orphan_grace_s;
      p.fault_hook = o.fault_hook;
      return std::make_unique<PostgresMapStore>(std::move(p));
    }
    SqliteStoreOptions s;
    s.orphan_grace_s = o.orphan_grace_s;
    s.fault_hook = o.fault_hook;
    return std::make_unique<SqliteMapStore>(tmp_->path() / "map.db", std::move(s));
  }

  /// The test's main store object (opened on first use).
  MapStore& store() {
    if (!store_) store_ = open();
    return *store_;
  }
  /// Closes the main store object (the next store() reopens).
  void close() { store_.reset(); }

  /// True if this object owns the store (sweeps at open).
  static bool owns(const MapStore& s) {
    if (const auto* q = dynamic_cast<const SqliteMapStore*>(&s)) return q->owns_store();
    if (const auto* p = dynamic_cast<const PostgresMapStore*>(&s)) return p->owns_store();
    return false;
  }

  [[nodiscard]] const std::filesystem::path& tmp() const { return tmp_->path(); }
  /// Where the backend keeps packages (<hash>/ each) and upload session files.
  [[nodiscard]] const std::filesystem::path& drive_dir() const { return drive_dir_; }
  [[nodiscard]] const std::filesystem::path& upload_dir() const { return upload_dir_; }
  /// The PostgreSQL database's URL (postgres only).
  [[nodiscard]] const std::string& url() const { return url_; }

 private:
  std::unique_ptr<polmap::test::TestDir> tmp_;
  std::unique_ptr<MapStore> store_;
  std::filesystem::path drive_dir_, upload_dir_;
  std::string url_;
};

inline std::string backend_name(const ::testing::TestParamInfo<std::string>& info) {
  return info.param;
}

}  // namespace polmap::mapping::testing

/// Runs the TEST_Ps of a StoreContract fixture on both backends.
#define POLMAP_STORE_CONTRACT_BACKENDS(Fixture)                                        \
  INSTANTIATE_TEST_SUITE_P(Backends, Fixture, ::testing::Values("sqlite", "postgres"), \
                           ::polmap::mapping::testing::backend_name)
