#pragma once
/// @file sha256.hpp
/// The one SHA-256 of the project (OpenSSL EVP). Every OpenSSL return code is checked;
/// a failure throws polmap::Error (it means a broken crypto library, not bad input).
#include <string>
#include <string_view>

namespace polmap::util {

/// Incremental SHA-256.
class Sha256 {
 public:
  Sha256();
  ~Sha256();
  Sha256(const Sha256&) = delete;
  Sha256& operator=(const Sha256&) = delete;

  void update(std::string_view bytes);
  /// Lower-case hex digest (64 characters); the object is finished afterwards.
  [[nodiscard]] std::string hex();

 private:
  void* ctx_ = nullptr;
};

/// SHA-256 of `bytes` as 64 lower-case hex digits.
[[nodiscard]] std::string sha256_hex(std::string_view bytes);

/// Compares two secrets in time independent of where they differ (compares their
/// SHA-256 digests with CRYPTO_memcmp, so the length is not leaked either).
[[nodiscard]] bool secrets_equal(std::string_view a, std::string_view b);

}  // namespace polmap::util
