// `polmap migrate --from URL_OR_FILE --to URL_OR_FILE [--package-dir DIR] [--copy]`: copies a
// whole map store into an empty store of the other backend (or the same one) with
// transfer_store (store_transfer.hpp), then verifies the copy (verify_store_transfer: rows
// per table, tile ETags, landmarks and tiles of every published version) and prints a
// summary. docs/operations.md describes when and how.
#include <CLI/CLI.hpp>
#include <chrono>
#include <cstdio>
#include <memory>
#include <string>

#include "command.hpp"
#include "map_db.hpp"
#include "polmap/mapping_service/store_transfer.hpp"
#include "polmap/schema/errors.hpp"
#include "progress.hpp"

namespace polmap::cli {
namespace {

struct MigrateOptions {
  std::string from;
  std::string to;
  std::string package_dir;
  bool copy = false;
};

void run(const MigrateOptions& o) {
  require_map_db(o.from);  // a missing SQLite file would otherwise be a new, empty store
  if (o.from == o.to) throw ValidationError("--from and --to name the same store");
  const auto t0 = std::chrono::steady_clock::now();
  mapping::StoreTransferOptions opt;
  opt.package_dir = o.package_dir;
  opt.hard_link_packages = !o.copy;
  std::unique_ptr<Progress> bar;
  std::string table;
  opt.progress = [&](const mapping::StoreTransferProgress& p) {
    if (p.table != table) {
      table = p.table;
      bar = std::make_unique<Progress>("migrate " + p.table, static_cast<double>(p.total));
    }
    bar->update(static_cast<double>(p.done),
                std::to_string(p.done) + "/" + std::to_string(p.total));
  };
  const mapping::StoreTransferReport r = mapping::transfer_store(o.from, o.to, opt);
  bar.reset();
  std::int64_t rows = 0;
  for (const auto& t : r.tables) rows += t.rows;
  std::printf("copied %zu tables, %lld rows (schema version %d)\n", r.tables.size(),
              static_cast<long long>(rows), r.schema_version);
  for (const auto& t : r.tables) {
    std::printf("  %-24s %10lld\n", t.table.c_str(), static_cast<long long>(t.rows));
  }
  for (const auto& t : r.transient_tables) {
    std::printf("  %-24s    skipped (transient)\n", t.c_str());
  }
  std::printf("packages: %lld (%lld files, %lld bytes, %lld hard-linked), upload files: %lld\n",
              static_cast<long long>(r.packages), static_cast<long long>(r.package_files),
              static_cast<long long>(r.package_bytes), static_cast<long long>(r.linked_files),
              static_cast<long long>(r.upload_files));

  const mapping::StoreVerifyReport v = mapping::verify_store_transfer(o.from, o.to);
  for (const auto& m : v.mismatches) std::fprintf(stderr, "migrate: verify: %s\n", m.c_str());
  const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  if (!v.ok()) {
    throw IoError("the copy in " + o.to + " differs from the source in " +
                  std::to_string(v.mismatches.size()) + " place(s) (listed above)");
  }
  std::printf(
      "verified: row counts of %zu tables equal, %lld tile ETags re-hashed, %lld landmarks of "
      "%lld published versions equal (%.1f s)\n",
      v.tables.size(), static_cast<long long>(v.tile_blobs_checked),
      static_cast<long long>(v.landmarks_compared), static_cast<long long>(v.versions_compared), s);
}

void setup(CLI::App& app) {
  auto opts = std::make_shared<MigrateOptions>();
  CLI::App* cmd = app.add_subcommand(
      "migrate",
      "Copy a map store into an empty store of the other backend (SQLite <-> PostgreSQL) "
      "without loss, then verify the copy");
  cmd->add_option("--from", opts->from,
                  "Source store: a SQLite database file or a PostgreSQL URL (postgresql://...)")
      ->required();
  cmd->add_option("--to", opts->to,
                  "Destination (must be empty): a SQLite file (created) or a PostgreSQL URL")
      ->required();
  cmd->add_option("--package-dir", opts->package_dir,
                  "PostgreSQL destination: its shared package directory (required for a new "
                  "database)");
  cmd->add_flag("--copy", opts->copy,
                "Copy package files instead of hard-linking them where possible");
  cmd->callback([opts] { run(*opts); });
}

}  // namespace
POLMAP_REGISTER_COMMAND(migrate, setup);
}  // namespace polmap::cli
