// Ed25519 signatures: RFC 8032 test vector 1 verifies, a signature made here verifies with
// the derived public key and with nothing else, and any change to the message or the
// signature is refused; keys of other types are refused with ValidationError.
#include "polmap/util/ed25519.hpp"

#include <gtest/gtest.h>

#include "polmap/schema/errors.hpp"

namespace polmap::util {
namespace {

// RFC 8032 §7.1 TEST 1: public key d75a98...511a, empty message, signature e5564300...100b,
// as a SubjectPublicKeyInfo PEM (30 2a 30 05 06 03 2b 65 70 03 21 00 || key).
constexpr const char* kRfcPublicPem =
    "-----BEGIN PUBLIC KEY-----\n"
    "MCowBQYDK2VwAyEA11qYAYKxCrfVS/7TyWQHOg7hcvPapiMlrwIaaPcHURo=\n"
    "-----END PUBLIC KEY-----\n";
constexpr const char* kRfcSignature =
    "e5564300c360ac729086e2cc806e828a84877f1eb8e5d974d873e06522490155"
    "5fb8821590a33bacc61e39701cf9b46bd25bf5f0595bbe24655141438e7a100b";

TEST(Ed25519, Rfc8032TestVectorVerifies) {
  EXPECT_TRUE(ed25519_verify_hex(kRfcPublicPem, "", kRfcSignature));
  EXPECT_FALSE(ed25519_verify_hex(kRfcPublicPem, "x", kRfcSignature));
}

TEST(Ed25519, SignVerifyAndEveryChangeRefused) {
  const Ed25519KeyPair k = ed25519_generate();
  EXPECT_EQ(ed25519_public_of(k.private_pem), k.public_pem);
  const std::string msg = "{\"map_version\":7,\"tiles\":[]}";
  const std::string sig = ed25519_sign_hex(k.private_pem, msg);
  ASSERT_EQ(sig.size(), 128U);
  EXPECT_TRUE(ed25519_verify_hex(k.public_pem, msg, sig));
  std::string other = msg;
  other[5] ^= 1;
  EXPECT_FALSE(ed25519_verify_hex(k.public_pem, other, sig));
  std::string bad = sig;
  bad[10] = bad[10] == '0' ? '1' : '0';
  EXPECT_FALSE(ed25519_verify_hex(k.public_pem, msg, bad));
  EXPECT_FALSE(ed25519_verify_hex(k.public_pem, msg, sig.substr(0, 126)));
  EXPECT_FALSE(ed25519_verify_hex(k.public_pem, msg, std::string(128, 'z')));
  const Ed25519KeyPair stranger = ed25519_generate();
  EXPECT_FALSE(ed25519_verify_hex(stranger.public_pem, msg, sig));
  EXPECT_EQ(ed25519_key_id(k.public_pem).size(), 16U);
  EXPECT_NE(ed25519_key_id(k.public_pem), ed25519_key_id(stranger.public_pem));
}

TEST(Ed25519, RefusesKeysThatAreNotEd25519) {
  EXPECT_THROW((void)ed25519_sign_hex("not a key", "m"), ValidationError);
  EXPECT_THROW(
      (void)ed25519_verify_hex("-----BEGIN PUBLIC KEY-----\nAAAA\n-----END PUBLIC KEY-----\n", "m",
                               kRfcSignature),
      ValidationError);
  // A public key where a private one is needed.
  EXPECT_THROW((void)ed25519_sign_hex(kRfcPublicPem, "m"), ValidationError);
}

}  // namespace
}  // namespace polmap::util
