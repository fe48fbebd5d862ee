#pragma once
/// @file ed25519.hpp
/// Ed25519 signatures (RFC 8032, OpenSSL EVP) for signed map publications: the publisher
/// signs a manifest with its private key, a vehicle checks it with the public key it was
/// given, so a CDN or mirror cannot alter a map. Keys are PEM files (PKCS#8 private key,
/// SubjectPublicKeyInfo public key), as `openssl genpkey -algorithm ed25519` writes them.
/// Every OpenSSL return code is checked.
#include <filesystem>
#include <string>
#include <string_view>

namespace polmap::util {

/// A fresh key pair as PEM text.
struct Ed25519KeyPair {
  std::string private_pem;
  std::string public_pem;
};
[[nodiscard]] Ed25519KeyPair ed25519_generate();

/// The public key (PEM) of a private key (PEM). ValidationError if it is not an Ed25519
/// private key.
[[nodiscard]] std::string ed25519_public_of(std::string_view private_pem);

/// Signature (64 bytes, as 128 lower-case hex digits) of `message`. ValidationError if the
/// key is not an Ed25519 private key.
[[nodiscard]] std::string ed25519_sign_hex(std::string_view private_pem, std::string_view message);

/// True if `signature_hex` is a valid signature of `message` under `public_pem`; false for
/// a wrong, malformed or mis-sized signature. ValidationError if the key is not an Ed25519
/// public key.
[[nodiscard]] bool ed25519_verify_hex(std::string_view public_pem, std::string_view message,
                                      std::string_view signature_hex);

/// Key identifier: the first 16 hex digits of SHA-256 of the raw 32-byte public key (what
/// a manifest names, so a vehicle can tell which key signed it).
[[nodiscard]] std::string ed25519_key_id(std::string_view public_pem);

}  // namespace polmap::util
