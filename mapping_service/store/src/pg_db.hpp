#pragma once
// The libpq wrapper of the PostgreSQL store backend: a connection with a prepared-statement
// cache, parameters sent in binary (never spliced into SQL text), RAII results read in
// binary, and a transaction guard. Every libpq error becomes an exception of
// schema/errors.hpp naming the statement and PostgreSQL's message and SQLSTATE; the
// conninfo (which may hold a password) is never part of a message. Internal to polmap_store.
#include <libpq-fe.h>

#include <bit>
#include <cstdint>
#include <cstring>
#include <optional>
#include <string>
#include <string_view>
#include <unordered_map>
#include <vector>

#include "polmap/mapping_service/store.hpp"
#include "polmap/schema/errors.hpp"

namespace polmap::mapping::pg {

// Type OIDs of pg_type (stable across PostgreSQL versions).
inline constexpr Oid kBoolOid = 16;
inline constexpr Oid kByteaOid = 17;
inline constexpr Oid kNameOid = 19;
inline constexpr Oid kInt8Oid = 20;
inline constexpr Oid kInt2Oid = 21;
inline constexpr Oid kInt4Oid = 23;
inline constexpr Oid kTextOid = 25;
inline constexpr Oid kJsonOid = 114;
inline constexpr Oid kFloat4Oid = 700;
inline constexpr Oid kFloat8Oid = 701;
inline constexpr Oid kBpcharOid = 1042;
inline constexpr Oid kVarcharOid = 1043;
inline constexpr Oid kJsonbOid = 3802;
inline constexpr Oid kInt8ArrayOid = 1016;
inline constexpr Oid kInt4ArrayOid = 1007;
inline constexpr Oid kFloat8ArrayOid = 1022;
inline constexpr Oid kByteaArrayOid = 1001;
inline constexpr Oid kTextArrayOid = 1009;

/// The parts of a conninfo that may be shown ("host:port/dbname as user"), never the
/// password or other options. "the configured database" if it does not parse.
inline std::string describe_conninfo(const std::string& conninfo) {
  char* err = nullptr;
  PQconninfoOption* opts = PQconninfoParse(conninfo.c_str(), &err);
  if (opts == nullptr) {
    if (err != nullptr) PQfreemem(err);
    return "the configured database (malformed conninfo)";
  }
  std::string host, port, db, user;
  for (const PQconninfoOption* o = opts; o->keyword != nullptr; ++o) {
    if (o->val == nullptr) continue;
    const std::string_view k = o->keyword;
    if (k == "host" || (k == "hostaddr" && host.empty())) host = o->val;
    if (k == "port") port = o->val;
    if (k == "dbname") db = o->val;
    if (k == "user") user = o->val;
  }
  PQconninfoFree(opts);
  std::string out = host.empty() ? "localhost" : host;
  if (!port.empty()) out += ":" + port;
  out += "/" + (db.empty() ? std::string("(default database)") : db);
  if (!user.empty()) out += " as " + user;
  return out;
}

/// SQLSTATE of a failed result ("" if none).
inline std::string sqlstate(const PGresult* r) {
  const char* s = r ? PQresultErrorField(r, PG_DIAG_SQLSTATE) : nullptr;
  return s ? s : "";
}

/// Throws the exception of errors.hpp that fits the failure: StorageFullError for a full
/// disk (53100), ValidationError for text PostgreSQL cannot store (a NUL character or
/// invalid UTF-8: 22P05, 22021), IoError otherwise.
[[noreturn]] inline void throw_pg(PGconn* c, const PGresult* r, const std::string& what) {
  const std::string state = sqlstate(r);
  std::string detail;
  if (r != nullptr && PQresultErrorField(r, PG_DIAG_MESSAGE_PRIMARY) != nullptr) {
    detail = PQresultErrorField(r, PG_DIAG_MESSAGE_PRIMARY);
  } else if (c != nullptr) {
    detail = PQerrorMessage(c);
  }
  while (!detail.empty() && (detail.back() == '\n' || detail.back() == ' ')) detail.pop_back();
  if (detail.empty()) detail = "unknown error";
  std::string msg = "postgresql: " + what + ": " + detail;
  if (!state.empty()) msg += " (SQLSTATE " + state + ")";
  if (state == "53100") throw StorageFullError("the store is full: " + msg);
  if (state == "22P05" || state == "22021") throw ValidationError(msg);
  throw IoError(msg);
}

/// A bytea parameter (text parameters are std::string_view / std::string).
struct Bytea {
  std::string_view bytes;
};
/// A NULL parameter of a type.
struct Null {
  Oid type;
};

/// Parameters $1, $2, ... in binary format.
class Params {
 public:
  Params& add(std::int64_t v) { return put(kInt8Oid, be64(static_cast<std::uint64_t>(v))); }
  Params& add(int v) {
    const std::uint32_t u = be32(static_cast<std::uint32_t>(v));
    return put(kInt4Oid, std::string(reinterpret_cast<const char*>(&u), 4));
  }
  Params& add(double v) { return put(kFloat8Oid, be64(std::bit_cast<std::uint64_t>(v))); }
  Params& add(bool v) { return put(kBoolOid, std::string(1, v ? '\1' : '\0')); }
  Params& add(std::string_view v) { return put(kTextOid, std::string(v)); }
  Params& add(const std::string& v) { return add(std::string_view(v)); }
  Params& add(const char* v) { return add(std::string_view(v)); }
  Params& add(Bytea v) { return put(kByteaOid, std::string(v.bytes)); }
  Params& add(Null n) {
    types_.push_back(n.type);
    values_.emplace_back();
    null_.push_back(true);
    return *this;
  }
  template <typename T>
  Params& add(const std::optional<T>& v) {
    if (!v) return add(Null{oid_of<T>()});
    return add(*v);
  }
  /// One-dimensional arrays (binary array format); nullopt elements are NULL.
  Params& add_array(const std::vector<std::int64_t>& v) {
    return array(kInt8ArrayOid, kInt8Oid, v.size(), [&](std::size_t i, std::string& out) {
      element(out, be64(static_cast<std::uint64_t>(v[i])));
    });
  }
  Params& add_array(const std::vector<int>& v) {
    return array(kInt4ArrayOid, kInt4Oid, v.size(), [&](std::size_t i, std::string& out) {
      const std::uint32_t u = be32(static_cast<std::uint32_t>(v[i]));
      element(out, std::string_view(reinterpret_cast<const char*>(&u), 4));
    });
  }
  Params& add_array(const std::vector<std::optional<std::int64_t>>& v) {
    return array(kInt8ArrayOid, kInt8Oid, v.size(), [&](std::size_t i, std::string& out) {
      if (v[i]) {
        element(out, be64(static_cast<std::uint64_t>(*v[i])));
      } else {
        null_element(out);
      }
    });
  }
  Params& add_array(const std::vector<std::optional<double>>& v) {
    return array(kFloat8ArrayOid, kFloat8Oid, v.size(), [&](std::size_t i, std::string& out) {
      if (v[i]) {
        element(out, be64(std::bit_cast<std::uint64_t>(*v[i])));
      } else {
        null_element(out);
      }
    });
  }
  Params& add_array(const std::vector<double>& v) {
    return array(kFloat8ArrayOid, kFloat8Oid, v.size(), [&](std::size_t i, std::string& out) {
      element(out, be64(std::bit_cast<std::uint64_t>(v[i])));
    });
  }
  /// text[] (nullopt: NULL).
  Params& add_array(const std::vector<std::optional<std::string>>& v) {
    return array(kTextArrayOid, kTextOid, v.size(), [&](std::size_t i, std::string& out) {
      if (v[i]) {
        element(out, *v[i]);
      } else {
        null_element(out);
      }
    });
  }
  /// bytea[] (e.g. WKB geometries).
  Params& add_bytea_array(const std::vector<std::string>& v) {
    return array(kByteaArrayOid, kByteaOid, v.size(),
                 [&](std::size_t i, std::string& out) { element(out, v[i]); });
  }

  [[nodiscard]] int size() const { return static_cast<int>(types_.size()); }
  [[nodiscard]] const std::vector<Oid>& types() const { return types_; }
  /// Pointers for PQexecPrepared (valid while this object lives unchanged).
  void pointers(std::vector<const char*>& values, std::vector<int>& lengths,
                std::vector<int>& formats) const {
    values.clear();
    lengths.clear();
    formats.clear();
    for (std::size_t i = 0; i < types_.size(); ++i) {
      values.push_back(null_[i] ? nullptr : values_[i].data());
      lengths.push_back(static_cast<int>(values_[i].size()));
      formats.push_back(1);
    }
  }

 private:
  template <typename T>
  static constexpr Oid oid_of() {
    if constexpr (std::is_same_v<T, std::int64_t>) return kInt8Oid;
    if constexpr (std::is_same_v<T, int>) return kInt4Oid;
    if constexpr (std::is_same_v<T, double>) return kFloat8Oid;
    if constexpr (std::is_same_v<T, bool>) return kBoolOid;
    return kTextOid;
  }
  static std::uint32_t be32(std::uint32_t v) {
    return std::endian::native == std::endian::little ? __builtin_bswap32(v) : v;
  }
  static std::string be64(std::uint64_t v) {
    if constexpr (std::endian::native == std::endian::little) v = __builtin_bswap64(v);
    return std::string(reinterpret_cast<const char*>(&v), 8);
  }
  static void put32(std::string& out, std::uint32_t v) {
    const std::uint32_t b = be32(v);
    out.append(reinterpret_cast<const char*>(&b), 4);
  }
  static void element(std::string& out, std::string_view bytes) {
    put32(out, static_cast<std::uint32_t>(bytes.size()));
    out.append(bytes);
  }
  static void null_element(std::string& out) { put32(out, 0xffffffffu); }
  template <typename F>
  Params& array(Oid array_type, Oid element_type, std::size_t n, F&& each) {
    // ndim, has-null flag (the server recomputes it), element type, then per dimension the
    // length and the lower bound; then each element as length + bytes (-1: NULL).
    std::string out;
    put32(out, 1);
    put32(out, 0);
    put32(out, element_type);
    put32(out, static_cast<std::uint32_t>(n));
    put32(out, 1);
    for (std::size_t i = 0; i < n; ++i) each(i, out);
    return put(array_type, std::move(out));
  }
  Params& put(Oid type, std::string bytes) {
    types_.push_back(type);
    values_.push_back(std::move(bytes));
    null_.push_back(false);
    return *this;
  }
  std::vector<Oid> types_;
  std::vector<std::string> values_;
  std::vector<bool> null_;
};

/// A query result in binary format; accessors check the column's type.
class Result {
 public:
  explicit Result(PGresult* r) : r_(r) {}
  ~Result() { PQclear(r_); }
  Result(Result&& o) noexcept : r_(o.r_) { o.r_ = nullptr; }
  Result& operator=(Result&& o) noexcept {
    if (this != &o) {
      PQclear(r_);
      r_ = o.r_;
      o.r_ = nullptr;
    }
    return *this;
  }
  Result(const Result&) = delete;
  Result& operator=(const Result&) = delete;

  [[nodiscard]] const PGresult* raw() const { return r_; }
  [[nodiscard]] int rows() const { return PQntuples(r_); }
  [[nodiscard]] bool empty() const { return rows() == 0; }
  /// Rows changed by INSERT/UPDATE/DELETE.
  [[nodiscard]] std::int64_t affected() const {
    const char* s = PQcmdTuples(r_);
    return (s && *s) ? std::stoll(s) : 0;
  }
  [[nodiscard]] bool is_null(int row, int col) const { return PQgetisnull(r_, row, col) != 0; }
  [[nodiscard]] std::int64_t i64(int row, int col) const {
    if (is_null(row, col)) return 0;
    const char* p = PQgetvalue(r_, row, col);
    switch (PQftype(r_, col)) {
      case kInt8Oid:
        return static_cast<std::int64_t>(load64(p));
      case kInt4Oid:
        return static_cast<std::int32_t>(load32(p));
      case kInt2Oid: {
        std::uint16_t u = 0;
        std::memcpy(&u, p, 2);
        if constexpr (std::endian::native == std::endian::little) u = __builtin_bswap16(u);
        return static_cast<std::int16_t>(u);
      }
      case kBoolOid:
        return *p != 0 ? 1 : 0;
      default:
        type_error(col, "an integer");
    }
  }
  [[nodiscard]] double f64(int row, int col) const {
    if (is_null(row, col)) return 0.0;
    const char* p = PQgetvalue(r_, row, col);
    switch (PQftype(r_, col)) {
      case kFloat8Oid:
        return std::bit_cast<double>(load64(p));
      case kFloat4Oid:
        return static_cast<double>(std::bit_cast<float>(load32(p)));
      default:
        type_error(col, "a float");
    }
  }
  /// text, varchar, name, json or jsonb ("" for NULL).
  [[nodiscard]] std::string text(int row, int col) const {
    if (is_null(row, col)) return {};
    const char* p = PQgetvalue(r_, row, col);
    const auto n = static_cast<std::size_t>(PQgetlength(r_, row, col));
    switch (PQftype(r_, col)) {
      case kTextOid:
      case kVarcharOid:
      case kBpcharOid:
      case kNameOid:
      case kJsonOid:
        return std::string(p, n);
      case kJsonbOid:  // binary jsonb: a version byte (1), then the text
        return n > 0 ? std::string(p + 1, n - 1) : std::string();
      default:
        type_error(col, "text");
    }
  }
  /// A one-dimensional bigint[] (empty for NULL or an empty array; NULL elements are 0).
  [[nodiscard]] std::vector<std::int64_t> i64_array(int row, int col) const {
    std::vector<std::int64_t> out;
    if (is_null(row, col)) return out;
    if (PQftype(r_, col) != kInt8ArrayOid) type_error(col, "bigint[]");
    const char* p = PQgetvalue(r_, row, col);
    const auto n = static_cast<std::size_t>(PQgetlength(r_, row, col));
    if (n < 12) return out;
    const std::uint32_t ndim = load32(p);
    if (ndim == 0) return out;
    if (ndim != 1 || n < 20) type_error(col, "a one-dimensional bigint[]");
    const std::uint32_t count = load32(p + 12);
    std::size_t at = 20;
    for (std::uint32_t k = 0; k < count && at + 4 <= n; ++k) {
      const auto len = static_cast<std::int32_t>(load32(p + at));
      at += 4;
      if (len < 0) {
        out.push_back(0);
        continue;
      }
      if (len != 8 || at + 8 > n) type_error(col, "bigint[] elements");
      out.push_back(static_cast<std::int64_t>(load64(p + at)));
      at += 8;
    }
    return out;
  }
  /// bytea ("" for NULL).
  [[nodiscard]] std::string bytes(int row, int col) const {
    if (is_null(row, col)) return {};
    if (PQftype(r_, col) != kByteaOid) type_error(col, "bytea");
    return std::string(PQgetvalue(r_, row, col),
                       static_cast<std::size_t>(PQgetlength(r_, row, col)));
  }

 private:
  static std::uint64_t load64(const char* p) {
    std::uint64_t u = 0;
    std::memcpy(&u, p, 8);
    if constexpr (std::endian::native == std::endian::little) u = __builtin_bswap64(u);
    return u;
  }
  static std::uint32_t load32(const char* p) {
    std::uint32_t u = 0;
    std::memcpy(&u, p, 4);
    if constexpr (std::endian::native == std::endian::little) u = __builtin_bswap32(u);
    return u;
  }
  [[noreturn]] void type_error(int col, const char* want) const {
    throw IoError(std::string("postgresql: column '") + PQfname(r_, col) + "' has type oid " +
                  std::to_string(PQftype(r_, col)) + ", not " + want + " (store bug)");
  }
  PGresult* r_;
};

/// One libpq connection (used by one thread at a time) with its prepared statements.
class Connection {
 public:
  /// Connects; IoError naming `description` (never the conninfo) on failure.
  Connection(const std::string& conninfo, const std::string& description) {
    const char* keys[] = {"application_name", "dbname", nullptr};
    const char* vals[] = {"polmap", conninfo.c_str(), nullptr};
    c_ = PQconnectdbParams(keys, vals, /*expand_dbname=*/1);
    if (c_ == nullptr)
      throw IoError("postgresql: cannot connect to " + description + ": out of memory");
    if (PQstatus(c_) != CONNECTION_OK) {
      std::string msg = PQerrorMessage(c_);
      while (!msg.empty() && (msg.back() == '\n' || msg.back() == ' ')) msg.pop_back();
      PQfinish(c_);
      c_ = nullptr;
      throw IoError("postgresql: cannot connect to " + description + ": " + msg);
    }
    PQsetNoticeProcessor(
        c_, [](void*, const char*) {}, nullptr);  // NOTICEs are not errors
  }
  ~Connection() {
    if (c_ != nullptr) PQfinish(c_);
  }
  Connection(const Connection&) = delete;
  Connection& operator=(const Connection&) = delete;

  /// True if the connection can be reused: open and outside any transaction.
  [[nodiscard]] bool reusable() const {
    return PQstatus(c_) == CONNECTION_OK && PQtransactionStatus(c_) == PQTRANS_IDLE;
  }

  /// Runs SQL text without parameters (DDL, BEGIN/COMMIT; may hold several statements);
  /// returns the command status of the last one (e.g. "COMMIT", "ROLLBACK").
  std::string exec(std::string_view sql) {
    const std::string s(sql);
    Result r(PQexec(c_, s.c_str()));
    check(r, s);
    return PQcmdStatus(const_cast<PGresult*>(r.raw()));
  }

  /// A statement with parameters, prepared once per connection (cached by its text and
  /// parameter types), results in binary.
  Result query(const std::string& sql, const Params& p) {
    std::string key = sql;
    key.push_back('\0');
    for (Oid t : p.types()) key += std::to_string(t) + ",";
    auto it = prepared_.find(key);
    if (it == prepared_.end()) {
      const std::string name = "polmap_" + std::to_string(prepared_.size() + 1);
      Result r(PQprepare(c_, name.c_str(), sql.c_str(), p.size(), p.types().data()));
      check(r, "prepare " + sql);
      it = prepared_.emplace(std::move(key), name).first;
    }
    std::vector<const char*> values;
    std::vector<int> lengths, formats;
    p.pointers(values, lengths, formats);
    Result r(PQexecPrepared(c_, it->second.c_str(), p.size(), values.data(), lengths.data(),
                            formats.data(), /*resultFormat=*/1));
    check(r, sql);
    return r;
  }

  /// query() with the arguments as parameters $1, $2, ...
  template <typename... A>
  Result run(const std::string& sql, const A&... args) {
    Params p;
    (p.add(args), ...);
    return query(sql, p);
  }

 private:
  void check(const Result& r, const std::string& sql) {
    const PGresult* raw = r.raw();
    const ExecStatusType st = raw ? PQresultStatus(raw) : PGRES_FATAL_ERROR;
    if (st == PGRES_COMMAND_OK || st == PGRES_TUPLES_OK) return;
    std::string shown = sql.substr(0, 120);
    for (char& ch : shown) {
      if (ch == '\n') ch = ' ';
    }
    throw_pg(c_, raw, "'" + shown + (sql.size() > 120 ? "...'" : "'"));
  }
  PGconn* c_ = nullptr;
  std::unordered_map<std::string, std::string> prepared_;
};

/// A transaction on one connection: BEGIN on construction, commit() to keep the work;
/// destroyed without commit() (an exception on the way), it rolls back.
class Transaction {
 public:
  enum class Mode {
    ReadCommitted,  ///< writers: each statement sees what committed before it
    Snapshot,       ///< readers: one consistent snapshot, read only
  };
  explicit Transaction(Connection& c, Mode mode = Mode::ReadCommitted) : c_(c) {
    c_.exec(mode == Mode::Snapshot ? "BEGIN ISOLATION LEVEL REPEATABLE READ READ ONLY" : "BEGIN");
  }
  ~Transaction() {
    if (done_) return;
    try {
      c_.exec("ROLLBACK");
    } catch (...) {  // a broken connection: the server rolls back; the pool drops it
    }
  }
  Transaction(const Transaction&) = delete;
  Transaction& operator=(const Transaction&) = delete;

  void commit() {
    const std::string status = c_.exec("COMMIT");
    done_ = true;
    // COMMIT of a transaction that an error aborted answers ROLLBACK, not an error.
    if (status != "COMMIT") throw IoError("postgresql: the transaction was rolled back");
  }

 private:
  Connection& c_;
  bool done_ = false;
};

}  // namespace polmap::mapping::pg
