#pragma once
/// @file errors.hpp
/// The one exception hierarchy of polmap, thrown at adapters (files, HTTP,
/// databases, CLI). Core computations use contract checks and
/// std::expected-style results instead.
#include <cstdint>
#include <stdexcept>
#include <string>

namespace polmap {

/// Root of every polmap exception.
class Error : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// A file, payload or record does not follow its documented format.
/// The message names the file (or request) and, where known, the byte offset.
class FormatError : public Error {
 public:
  FormatError(const std::string& source, std::uint64_t offset, const std::string& what)
      : Error(source + " at byte " + std::to_string(offset) + ": " + what),
        source_(source),
        offset_(offset) {}
  explicit FormatError(const std::string& what) : Error(what) {}
  [[nodiscard]] const std::string& source() const { return source_; }
  [[nodiscard]] std::uint64_t offset() const { return offset_; }

 private:
  std::string source_;
  std::uint64_t offset_ = 0;
};

/// Input is well-formed but semantically invalid (a field out of range, ...).
class ValidationError : public Error {
 public:
  using Error::Error;
};

/// Operating-system level I/O failure (cannot open, cannot write).
class IoError : public Error {
 public:
  using Error::Error;
};

/// A write found no space (HTTP 507): the database or a file system is full (SQLITE_FULL,
/// ENOSPC, EDQUOT). The write is rolled back as any failed write is; reads keep working,
/// and the same write succeeds once space returns.
class StorageFullError : public IoError {
 public:
  using IoError::IoError;
};

/// A requested object (drive, map version, tile) does not exist.
class NotFoundError : public Error {
 public:
  using Error::Error;
};

/// A violated precondition inside the core: a programming error, not bad input.
class ContractViolation : public Error {
 public:
  using Error::Error;
};

}  // namespace polmap

/// Contract check for the core: throws ContractViolation with the condition text.
#define POLMAP_EXPECT(cond)                                                                      \
  do {                                                                                           \
    if (!(cond)) {                                                                               \
      throw ::polmap::ContractViolation(std::string(__FILE__) + ":" + std::to_string(__LINE__) + \
                                        ": expected " #cond);                                    \
    }                                                                                            \
  } while (false)
