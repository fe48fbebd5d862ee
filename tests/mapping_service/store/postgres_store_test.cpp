// What is PostgreSQL's own in PostgresMapStore, against this binary's throw-away cluster
// (store_backends.hpp): migrations from schema/store_postgres.sql, applied once (also by
// concurrent openers), the package directory recorded at the first open, two store objects
// on one database ("replicas") seeing each other's writes and putting one drive at once, a
// running build never failed by another opener, and messages without the password.
#include <gtest/gtest.h>

#include <atomic>
#include <fstream>
#include <thread>

#include "mapping_service/store/contract_packages.hpp"
#include "mapping_service/store/store_backends.hpp"
#include "polmap/mapping_service/open_store.hpp"

namespace polmap::mapping::testing {
namespace {
namespace fs = std::filesystem;

class PostgresStore : public ::testing::Test {
 protected:
  void SetUp() override { url_ = PostgresCluster::instance().create_database(); }
  PostgresStoreOptions options() const {
    PostgresStoreOptions o;
    o.conninfo = url_;
    o.package_dir = tmp_.path() / "packages";
    return o;
  }
  std::string count(const std::string& sql) const {
    return PostgresCluster::instance().scalar(url_, sql);
  }
  polmap::test::TestDir tmp_{"postgres_store"};
  std::string url_;
};

TEST_F(PostgresStore, MigrationsAreTheSectionsOfStorePostgresSqlAppliedOnce) {
  std::ifstream f(std::string(POLMAP_SOURCE_DIR) + "/schema/store_postgres.sql");
  ASSERT_TRUE(f) << "schema/store_postgres.sql missing";
  const std::string text((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
  const auto& m = postgres_store_migrations();
  ASSERT_GE(m.size(), 2U);
  for (std::size_t i = 0; i < m.size(); ++i) {
    EXPECT_EQ(m[i].version, static_cast<int>(i));
    EXPECT_NE(text.find(std::string(m[i].sql)), std::string::npos) << "migration " << i;
  }
  EXPECT_EQ(m[1].name, "initial schema");
  // Four openers at once: one applies the migrations, the others wait and find them done.
  std::vector<std::thread> threads;
  std::atomic<int> ok{0};
  for (int t = 0; t < 4; ++t) {
    threads.emplace_back([&] {
      PostgresMapStore s(options());
      if (s.schema_version() == m.back().version) ++ok;
    });
  }
  for (auto& t : threads) t.join();
  EXPECT_EQ(ok, 4);
  EXPECT_EQ(count("SELECT COUNT(*) FROM schema_migrations"), std::to_string(m.size() - 1));
  EXPECT_EQ(count("SELECT COUNT(*) FROM pg_indexes WHERE indexname = 'candidates_geom' AND "
                  "indexdef LIKE '%USING gist%'"),
            "1");
  EXPECT_EQ(count("SELECT value FROM store_settings WHERE key = 'package_dir'"),
            (tmp_.path() / "packages").string());
}

TEST_F(PostgresStore, ThePackageDirectoryIsRecordedAtTheFirstOpen) {
  PostgresStoreOptions none = options();
  none.package_dir.clear();
  try {
    PostgresMapStore s(none);
    FAIL() << "opened without a package directory";
  } catch (const ValidationError& e) {
    EXPECT_NE(std::string(e.what()).find("package directory"), std::string::npos) << e.what();
  }
  { PostgresMapStore first(options()); }
  PostgresMapStore later(none);  // recorded: no need to name it again
  EXPECT_EQ(later.package_dir(), tmp_.path() / "packages");
  EXPECT_EQ(later.upload_session_dir(), tmp_.path() / "packages" / "uploads");
  PostgresStoreOptions same = options();
  same.package_dir = tmp_.path() / "x" / ".." / "packages" / "";
  EXPECT_NO_THROW(PostgresMapStore{same});  // the same directory, spelled differently
  PostgresStoreOptions other = options();
  other.package_dir = tmp_.path() / "elsewhere";
  EXPECT_THROW(PostgresMapStore{other}, ValidationError);
}

TEST_F(PostgresStore, TwoReplicasSeeEachOthersWritesAndPutOneDriveOnce) {
  PostgresMapStore a(options());
  PostgresMapStore b(options());
  EXPECT_TRUE(a.owns_store());
  EXPECT_FALSE(b.owns_store());
  // The same drive through both at once: one drive, one package directory.
  const auto pkg = make_package("shared", 30, 4, 1);
  const auto [tar, hash] = write_archive(tmp_.path(), "shared", "shared bytes");
  std::atomic<int> inserted{0};
  std::vector<PutDriveResult> results(2);
  std::thread ta([&] { results[0] = a.put_drive(pkg, tar, hash); });
  std::thread tb([&] { results[1] = b.put_drive(pkg, tar, hash); });
  ta.join();
  tb.join();
  for (const auto& r : results) {
    if (r.status == PutDriveResult::Status::Inserted) ++inserted;
  }
  EXPECT_EQ(inserted, 1);
  EXPECT_EQ(results[0].drive.row, results[1].drive.row);
  EXPECT_EQ(count("SELECT COUNT(*) FROM drives"), "1");
  EXPECT_EQ(count("SELECT COUNT(*) FROM candidates"), "34");
  EXPECT_EQ(entries(a.package_dir()), 1U);
  // Writes of one are reads of the other.
  EXPECT_EQ(b.get_drive("shared")->content_hash, hash);
  const auto v = b.begin_map_version({{"notes", "on b"}});
  b.publish_map_version(v, {});
  EXPECT_EQ(a.current_map_version(), v);
  EXPECT_TRUE(a.delete_drive("shared"));
  EXPECT_FALSE(b.get_drive("shared").has_value());
  UploadSessionRequest req;
  req.owner = "k";
  req.length_bytes = 5;
  const auto u = a.create_upload_session(req);
  EXPECT_TRUE(b.advance_upload_offset(u.session.id, 0, 5));
  EXPECT_EQ(a.get_upload_session(u.session.id)->offset_bytes, 5U);
}

TEST_F(PostgresStore, TheOwnersSweepFailsAbandonedBuildsButNotARunningOne) {
  PostgresStoreOptions o = options();
  o.orphan_grace_s = 0.0;
  auto owner = std::make_unique<PostgresMapStore>(o);
  EXPECT_TRUE(owner->owns_store());
  PostgresMapStore builder(o);  // another replica, building
  const std::int64_t running = builder.begin_map_version({{"notes", "running"}});
  std::int64_t abandoned = 0;
  {
    PostgresMapStore crashed(o);
    abandoned = crashed.begin_map_version({{"notes", "abandoned"}});
  }  // its process is gone, and the lock of its build with it
  owner.reset();
  PostgresMapStore restarted(o);  // the new owner sweeps at open
  EXPECT_TRUE(restarted.owns_store());
  EXPECT_EQ(restarted.get_map_version(abandoned)->status, MapVersionStatus::Failed);
  EXPECT_EQ(restarted.get_map_version(running)->status, MapVersionStatus::Building);
  builder.publish_map_version(running, {});
  EXPECT_EQ(restarted.current_map_version(), running);
}

TEST_F(PostgresStore, ALiveReplicaFailsTheBuildsOfOneThatDiedWithoutWaitingForAnOpen) {
  PostgresMapStore owner(options());
  PostgresMapStore builder(options());
  const std::int64_t running = builder.begin_map_version({{"notes", "running"}});
  std::int64_t queued = 0, started = 0;
  {
    PostgresMapStore killed(options());
    queued = killed.begin_map_version({{"notes", "queued"}});
    started = killed.begin_map_version({{"notes", "started"}});
    killed.put_landmarks(started, std::vector<StoredPointLandmark>{}, {});
  }  // its process is gone, and the locks of its builds with it
  // Any opener may ask, not only the owner, and no grace period applies.
  PostgresMapStore other(options());
  EXPECT_FALSE(other.owns_store());
  EXPECT_EQ(other.fail_abandoned_builds(), (std::vector<std::int64_t>{queued, started}));
  EXPECT_EQ(other.get_map_version(queued)->status, MapVersionStatus::Failed);
  EXPECT_EQ(other.get_map_version(started)->error, "interrupted (the process building it is gone)");
  EXPECT_EQ(other.get_map_version(running)->status, MapVersionStatus::Building);
  EXPECT_TRUE(other.fail_abandoned_builds().empty());  // nothing more, nothing twice
  builder.publish_map_version(running, {});
  EXPECT_EQ(owner.current_map_version(), running);
}

TEST_F(PostgresStore, ABuilderWhoseSessionBrokeTakesItsLocksAgain) {
  PostgresMapStore builder(options());
  PostgresMapStore other(options());
  const std::int64_t v = builder.begin_map_version({{"notes", "long build"}});
  // The database ends the builder's session connection (restart, network), and its locks.
  const std::string holders = "FROM pg_locks WHERE locktype = 'advisory' AND classid = " +
                              std::to_string(0x706d6171) /* kBuildLockClass */ +
                              " AND objid = " + std::to_string(v) + " AND objsubid = 2";
  ASSERT_EQ(count("SELECT COUNT(pg_terminate_backend(pid)) " + holders), "1");
  for (int i = 0; i < 100 && count("SELECT COUNT(*) " + holders) != "0"; ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  // Its next store call that needs the session reconnects and locks its build again.
  EXPECT_TRUE(builder.fail_abandoned_builds().empty());
  EXPECT_EQ(count("SELECT COUNT(*) " + holders), "1");
  EXPECT_TRUE(other.fail_abandoned_builds().empty());
  EXPECT_EQ(other.get_map_version(v)->status, MapVersionStatus::Building);
  builder.publish_map_version(v, {});
  EXPECT_EQ(other.current_map_version(), v);
}

TEST_F(PostgresStore, ConnectionErrorsNameTheServerButNeverThePassword) {
  PostgresStoreOptions o = options();
  o.conninfo = "postgresql://polmap:s3cret-pw@127.0.0.1:1/nowhere?connect_timeout=2";
  try {
    PostgresMapStore s(o);
    FAIL() << "connected to port 1";
  } catch (const IoError& e) {
    const std::string what = e.what();
    EXPECT_EQ(what.find("s3cret-pw"), std::string::npos) << what;
    EXPECT_NE(what.find("127.0.0.1:1/nowhere"), std::string::npos) << what;
  }
}

TEST_F(PostgresStore, OpenMapStorePicksTheBackendFromTheDbString) {
  EXPECT_TRUE(is_postgres_conninfo("postgresql://u@h/db"));
  EXPECT_TRUE(is_postgres_conninfo("postgres://h/db"));
  EXPECT_TRUE(is_postgres_conninfo("host=h dbname=d"));
  EXPECT_TRUE(is_postgres_conninfo("dbname=d"));
  EXPECT_FALSE(is_postgres_conninfo("/var/lib/polmap/map.db"));
  EXPECT_FALSE(is_postgres_conninfo("map.db"));
  const auto pg = open_map_store(url_, {.package_dir = tmp_.path() / "packages"});
  EXPECT_NE(dynamic_cast<PostgresMapStore*>(pg.get()), nullptr);
  const auto lite = open_map_store((tmp_.path() / "map.db").string());
  EXPECT_NE(dynamic_cast<SqliteMapStore*>(lite.get()), nullptr);
  EXPECT_THROW(
      (void)open_map_store((tmp_.path() / "other.db").string(), {.package_dir = tmp_.path() / "p"}),
      ValidationError);
}

TEST_F(PostgresStore, TextPostgresCannotStoreIsAValidationError) {
  PostgresMapStore s(options());
  const auto v = s.begin_map_version({});
  EXPECT_THROW(s.fail_map_version(v, std::string("bad \xff\xfe utf-8")), ValidationError);
  EXPECT_THROW((void)s.begin_map_version({{"notes", std::string("nul \0 char", 10)}}),
               ValidationError);
  s.fail_map_version(v, "fine");
  EXPECT_EQ(s.get_map_version(v)->error, "fine");
}

}  // namespace
}  // namespace polmap::mapping::testing
