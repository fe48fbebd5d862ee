// Ed25519 through OpenSSL EVP (ed25519.hpp).
#include "polmap/util/ed25519.hpp"

#include <openssl/evp.h>
#include <openssl/pem.h>

#include <memory>

#include "polmap/schema/errors.hpp"
#include "polmap/util/sha256.hpp"

namespace polmap::util {
namespace {

using Key = std::unique_ptr<EVP_PKEY, decltype(&EVP_PKEY_free)>;
using Bio = std::unique_ptr<BIO, decltype(&BIO_free)>;
using MdCtx = std::unique_ptr<EVP_MD_CTX, decltype(&EVP_MD_CTX_free)>;

Bio memory_bio(std::string_view pem) {
  Bio b(BIO_new_mem_buf(pem.data(), static_cast<int>(pem.size())), &BIO_free);
  if (!b) throw Error("ed25519: BIO_new_mem_buf failed");
  return b;
}

Key read_key(std::string_view pem, bool is_private) {
  Bio b = memory_bio(pem);
  Key k(is_private ? PEM_read_bio_PrivateKey(b.get(), nullptr, nullptr, nullptr)
                   : PEM_read_bio_PUBKEY(b.get(), nullptr, nullptr, nullptr),
        &EVP_PKEY_free);
  if (!k || EVP_PKEY_id(k.get()) != EVP_PKEY_ED25519) {
    throw ValidationError(std::string("not an Ed25519 ") + (is_private ? "private" : "public") +
                          " key in PEM form");
  }
  return k;
}

std::string pem_of(EVP_PKEY* k, bool is_private) {
  Bio b(BIO_new(BIO_s_mem()), &BIO_free);
  if (!b) throw Error("ed25519: BIO_new failed");
  const int ok = is_private
                     ? PEM_write_bio_PrivateKey(b.get(), k, nullptr, nullptr, 0, nullptr, nullptr)
                     : PEM_write_bio_PUBKEY(b.get(), k);
  if (ok != 1) throw Error("ed25519: PEM write failed");
  char* data = nullptr;
  const long n = BIO_get_mem_data(b.get(), &data);
  return {data, static_cast<std::size_t>(n)};
}

int hex_value(char c) {
  if (c >= '0' && c <= '9') return c - '0';
  if (c >= 'a' && c <= 'f') return c - 'a' + 10;
  if (c >= 'A' && c <= 'F') return c - 'A' + 10;
  return -1;
}

}  // namespace

Ed25519KeyPair ed25519_generate() {
  std::unique_ptr<EVP_PKEY_CTX, decltype(&EVP_PKEY_CTX_free)> ctx(
      EVP_PKEY_CTX_new_id(EVP_PKEY_ED25519, nullptr), &EVP_PKEY_CTX_free);
  if (!ctx || EVP_PKEY_keygen_init(ctx.get()) != 1) throw Error("ed25519: keygen init failed");
  EVP_PKEY* raw = nullptr;
  if (EVP_PKEY_keygen(ctx.get(), &raw) != 1) throw Error("ed25519: keygen failed");
  const Key k(raw, &EVP_PKEY_free);
  return {pem_of(k.get(), true), pem_of(k.get(), false)};
}

std::string ed25519_public_of(std::string_view private_pem) {
  const Key k = read_key(private_pem, true);
  return pem_of(k.get(), false);
}

std::string ed25519_sign_hex(std::string_view private_pem, std::string_view message) {
  const Key k = read_key(private_pem, true);
  MdCtx ctx(EVP_MD_CTX_new(), &EVP_MD_CTX_free);
  if (!ctx || EVP_DigestSignInit(ctx.get(), nullptr, nullptr, nullptr, k.get()) != 1) {
    throw Error("ed25519: sign init failed");
  }
  unsigned char sig[64];
  std::size_t n = sizeof sig;
  if (EVP_DigestSign(ctx.get(), sig, &n, reinterpret_cast<const unsigned char*>(message.data()),
                     message.size()) != 1 ||
      n != sizeof sig) {
    throw Error("ed25519: signing failed");
  }
  static constexpr char kHex[] = "0123456789abcdef";
  std::string out;
  for (unsigned char b : sig) {
    out.push_back(kHex[b >> 4]);
    out.push_back(kHex[b & 15]);
  }
  return out;
}

bool ed25519_verify_hex(std::string_view public_pem, std::string_view message,
                        std::string_view signature_hex) {
  const Key k = read_key(public_pem, false);
  if (signature_hex.size() != 128) return false;
  unsigned char sig[64];
  for (std::size_t i = 0; i < 64; ++i) {
    const int hi = hex_value(signature_hex[2 * i]), lo = hex_value(signature_hex[2 * i + 1]);
    if (hi < 0 || lo < 0) return false;
    sig[i] = static_cast<unsigned char>(hi * 16 + lo);
  }
  MdCtx ctx(EVP_MD_CTX_new(), &EVP_MD_CTX_free);
  if (!ctx || EVP_DigestVerifyInit(ctx.get(), nullptr, nullptr, nullptr, k.get()) != 1) {
    throw Error("ed25519: verify init failed");
  }
  return EVP_DigestVerify(ctx.get(), sig, sizeof sig,
                          reinterpret_cast<const unsigned char*>(message.data()),
                          message.size()) == 1;
}

std::string ed25519_key_id(std::string_view public_pem) {
  const Key k = read_key(public_pem, false);
  unsigned char raw[32];
  std::size_t n = sizeof raw;
  if (EVP_PKEY_get_raw_public_key(k.get(), raw, &n) != 1 || n != sizeof raw) {
    throw Error("ed25519: raw public key unavailable");
  }
  return sha256_hex(std::string_view(reinterpret_cast<const char*>(raw), n)).substr(0, 16);
}

}  // namespace polmap::util
