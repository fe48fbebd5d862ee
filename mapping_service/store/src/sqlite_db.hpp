#pragma once
// The SQLite wrapper of the store backends: a connection with a prepared-statement
// cache, borrowed statements, and a transaction guard. Internal to polmap_store.
#include <sqlite3.h>

#include <cerrno>
#include <cstdint>
#include <filesystem>
#include <string>
#include <string_view>
#include <unordered_map>

#include "polmap/mapping_service/store.hpp"
#include "polmap/schema/errors.hpp"

namespace polmap::mapping::sqlite {

/// True if the connection's last error means "no space": SQLITE_FULL (a write got ENOSPC,
/// or max_page_count was reached) or an I/O error whose system errno is ENOSPC or EDQUOT.
inline bool storage_full(sqlite3* db, int rc) {
  if (db == nullptr) return false;
  if ((rc & 0xff) == SQLITE_FULL || (sqlite3_extended_errcode(db) & 0xff) == SQLITE_FULL) {
    return true;
  }
  const int e = sqlite3_system_errno(db);
  return (rc & 0xff) == SQLITE_IOERR && (e == ENOSPC || e == EDQUOT);
}

[[noreturn]] inline void throw_db(sqlite3* db, const std::string& what, int rc = SQLITE_ERROR) {
  const std::string msg = "sqlite: " + what + ": " + (db ? sqlite3_errmsg(db) : "out of memory");
  if (storage_full(db, rc)) throw StorageFullError("the store is full: " + msg);
  throw IoError(msg);
}

/// A prepared statement borrowed from a connection's cache; reset on destruction.
class Stmt {
 public:
  Stmt(sqlite3* db, sqlite3_stmt* s) : db_(db), s_(s) {}
  ~Stmt() {
    sqlite3_reset(s_);
    sqlite3_clear_bindings(s_);
  }
  Stmt(const Stmt&) = delete;
  Stmt& operator=(const Stmt&) = delete;

  Stmt& bind(int i, std::int64_t v) {
    check(sqlite3_bind_int64(s_, i, v));
    return *this;
  }
  Stmt& bind(int i, int v) { return bind(i, static_cast<std::int64_t>(v)); }
  Stmt& bind(int i, double v) {
    check(sqlite3_bind_double(s_, i, v));
    return *this;
  }
  Stmt& bind(int i, std::string_view v) {
    check(sqlite3_bind_text(s_, i, v.data(), static_cast<int>(v.size()), SQLITE_TRANSIENT));
    return *this;
  }
  Stmt& bind(int i, const char* v) { return bind(i, std::string_view(v)); }
  Stmt& bind(int i, const std::string& v) { return bind(i, std::string_view(v)); }
  Stmt& bind_blob(int i, std::string_view v) {
    check(sqlite3_bind_blob(s_, i, v.data(), static_cast<int>(v.size()), SQLITE_TRANSIENT));
    return *this;
  }
  Stmt& bind_null(int i) {
    check(sqlite3_bind_null(s_, i));
    return *this;
  }
  /// True while a row is available.
  bool step() {
    const int rc = sqlite3_step(s_);
    if (rc == SQLITE_ROW) return true;
    if (rc == SQLITE_DONE) return false;
    throw_db(db_, std::string("step '") + sqlite3_sql(s_) + "'", rc);
  }
  void run() {
    while (step()) {
    }
  }
  [[nodiscard]] std::int64_t i64(int c) const { return sqlite3_column_int64(s_, c); }
  [[nodiscard]] double f64(int c) const { return sqlite3_column_double(s_, c); }
  [[nodiscard]] bool is_null(int c) const { return sqlite3_column_type(s_, c) == SQLITE_NULL; }
  [[nodiscard]] std::string text(int c) const {
    const auto* p = sqlite3_column_text(s_, c);
    return p ? std::string(reinterpret_cast<const char*>(p),
                           static_cast<std::size_t>(sqlite3_column_bytes(s_, c)))
             : std::string();
  }
  [[nodiscard]] std::string blob(int c) const {
    const void* p = sqlite3_column_blob(s_, c);
    const int n = sqlite3_column_bytes(s_, c);
    return p ? std::string(static_cast<const char*>(p), static_cast<std::size_t>(n))
             : std::string();
  }

 private:
  void check(int rc) {
    if (rc != SQLITE_OK) throw_db(db_, "bind");
  }
  sqlite3* db_;
  sqlite3_stmt* s_;
};

class Connection {
 public:
  Connection(const std::filesystem::path& path, int busy_timeout_ms) {
    const int rc =
        sqlite3_open_v2(path.c_str(), &db_,
                        SQLITE_OPEN_READWRITE | SQLITE_OPEN_CREATE | SQLITE_OPEN_NOMUTEX, nullptr);
    if (rc != SQLITE_OK) {
      std::string msg = db_ ? sqlite3_errmsg(db_) : "out of memory";
      sqlite3_close(db_);
      throw IoError("cannot open map store database " + path.string() + ": " + msg);
    }
    sqlite3_busy_timeout(db_, busy_timeout_ms);
    exec("PRAGMA foreign_keys = ON");
    exec("PRAGMA journal_mode = WAL");
    exec("PRAGMA synchronous = NORMAL");
  }
  ~Connection() {
    for (auto& [sql, s] : cache_) sqlite3_finalize(s);
    sqlite3_close(db_);
  }
  Connection(const Connection&) = delete;
  Connection& operator=(const Connection&) = delete;

  void exec(std::string_view sql) {
    char* err = nullptr;
    const std::string s(sql);
    const int rc = sqlite3_exec(db_, s.c_str(), nullptr, nullptr, &err);
    if (rc != SQLITE_OK) {
      std::string msg =
          "sqlite: " + std::string(err ? err : "unknown error") + " (in: " + s.substr(0, 80) + ")";
      sqlite3_free(err);
      if (storage_full(db_, rc)) throw StorageFullError("the store is full: " + msg);
      throw IoError(msg);
    }
  }
  Stmt stmt(const std::string& sql) {
    auto it = cache_.find(sql);
    if (it == cache_.end()) {
      sqlite3_stmt* s = nullptr;
      if (sqlite3_prepare_v3(db_, sql.c_str(), static_cast<int>(sql.size()),
                             SQLITE_PREPARE_PERSISTENT, &s, nullptr) != SQLITE_OK) {
        throw_db(db_, "prepare '" + sql + "'");
      }
      it = cache_.emplace(sql, s).first;
    }
    return Stmt(db_, it->second);
  }
  [[nodiscard]] std::int64_t last_id() const { return sqlite3_last_insert_rowid(db_); }
  [[nodiscard]] int changes() const { return sqlite3_changes(db_); }

 private:
  sqlite3* db_ = nullptr;
  std::unordered_map<std::string, sqlite3_stmt*> cache_;
};

/// A transaction on one connection: BEGIN on construction, commit() to keep the work;
/// destroyed without commit() (an exception on the way), it rolls back.
class Transaction {
 public:
  enum class Mode { Deferred, Immediate };
  explicit Transaction(Connection& c, Mode mode = Mode::Deferred) : c_(c) {
    c_.exec(mode == Mode::Immediate ? "BEGIN IMMEDIATE" : "BEGIN");
  }
  ~Transaction() {
    if (done_) return;
    try {
      c_.exec("ROLLBACK");
    } catch (...) {  // nothing to roll back: the error came from COMMIT itself
    }
  }
  Transaction(const Transaction&) = delete;
  Transaction& operator=(const Transaction&) = delete;

  void commit() {
    c_.exec("COMMIT");  // on failure (e.g. busy) the destructor rolls back
    done_ = true;
  }

 private:
  Connection& c_;
  bool done_ = false;
};

}  // namespace polmap::mapping::sqlite
