#include "polmap/util/sha256.hpp"

#include <openssl/crypto.h>
#include <openssl/evp.h>

#include <array>

#include "polmap/schema/errors.hpp"

namespace polmap::util {
namespace {

using Digest = std::array<unsigned char, EVP_MAX_MD_SIZE>;

unsigned int digest(std::string_view bytes, Digest& md) {
  unsigned int len = 0;
  if (EVP_Digest(bytes.data(), bytes.size(), md.data(), &len, EVP_sha256(), nullptr) != 1 ||
      len != 32) {
    throw Error("OpenSSL: SHA-256 failed");
  }
  return len;
}

std::string to_hex(const Digest& md, unsigned int len) {
  static constexpr char kHex[] = "0123456789abcdef";
  std::string out;
  out.reserve(2 * len);
  for (unsigned int i = 0; i < len; ++i) {
    out.push_back(kHex[md[i] >> 4U]);
    out.push_back(kHex[md[i] & 15U]);
  }
  return out;
}

}  // namespace

Sha256::Sha256() {
  EVP_MD_CTX* ctx = EVP_MD_CTX_new();
  if (ctx == nullptr || EVP_DigestInit_ex(ctx, EVP_sha256(), nullptr) != 1) {
    EVP_MD_CTX_free(ctx);
    throw Error("OpenSSL: SHA-256 initialisation failed");
  }
  ctx_ = ctx;
}

Sha256::~Sha256() { EVP_MD_CTX_free(static_cast<EVP_MD_CTX*>(ctx_)); }

void Sha256::update(std::string_view bytes) {
  if (EVP_DigestUpdate(static_cast<EVP_MD_CTX*>(ctx_), bytes.data(), bytes.size()) != 1) {
    throw Error("OpenSSL: SHA-256 update failed");
  }
}

std::string Sha256::hex() {
  Digest md{};
  unsigned int len = 0;
  if (EVP_DigestFinal_ex(static_cast<EVP_MD_CTX*>(ctx_), md.data(), &len) != 1) {
    throw Error("OpenSSL: SHA-256 final failed");
  }
  return to_hex(md, len);
}

std::string sha256_hex(std::string_view bytes) {
  Digest md{};
  const unsigned int len = digest(bytes, md);
  return to_hex(md, len);
}

bool secrets_equal(std::string_view a, std::string_view b) {
  Digest da{}, db{};
  digest(a, da);
  digest(b, db);
  return CRYPTO_memcmp(da.data(), db.data(), 32) == 0;
}

}  // namespace polmap::util
