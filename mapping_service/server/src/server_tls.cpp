// mapping::Server's listening socket: plain cpp-httplib, or TLS (httplib::SSLServer) with
// a certificate and key checked before the server starts, so a wrong file is a clear
// start-up error rather than a server that fails every handshake.
#include <openssl/err.h>
#include <openssl/ssl.h>
#include <openssl/x509.h>

#include <cerrno>
#include <cstring>
#include <fstream>

#include "polmap/schema/errors.hpp"
#include "server_impl.hpp"

namespace polmap::mapping {
namespace {

/// The oldest error of OpenSSL's queue of this thread as text (the queue is cleared);
/// `mismatch` tells whether it says that a key does not belong to a certificate.
std::string openssl_error(bool* mismatch = nullptr) {
  const unsigned long code = ERR_get_error();
  ERR_clear_error();
  if (mismatch != nullptr) {
    *mismatch =
        ERR_GET_LIB(code) == ERR_LIB_X509 && (ERR_GET_REASON(code) == X509_R_KEY_VALUES_MISMATCH ||
                                              ERR_GET_REASON(code) == X509_R_KEY_TYPE_MISMATCH);
  }
  if (code == 0) return "unknown OpenSSL error";
  char buf[256];
  ERR_error_string_n(code, buf, sizeof buf);
  return buf;
}

void require_readable(const std::filesystem::path& path, const char* what) {
  std::ifstream in(path, std::ios::binary);
  if (!in || std::filesystem::is_directory(path)) {
    throw IoError(std::string("cannot read TLS ") + what + " " + path.string() + ": " +
                  (in ? "is a directory" : std::strerror(errno)));
  }
}

}  // namespace

std::unique_ptr<httplib::Server> make_http_server(const ServerConfig& cfg) {
  if (cfg.tls_cert_file.empty() && cfg.tls_key_file.empty()) {
    return std::make_unique<httplib::Server>();
  }
  if (cfg.tls_cert_file.empty() || cfg.tls_key_file.empty()) {
    throw ValidationError("TLS needs both a certificate and a private key (got only the " +
                          std::string(cfg.tls_cert_file.empty() ? "key" : "certificate") + ")");
  }
  require_readable(cfg.tls_cert_file, "certificate");
  require_readable(cfg.tls_key_file, "private key");
  const std::string cert = cfg.tls_cert_file.string();
  const std::string key = cfg.tls_key_file.string();
  std::string failure;
  ERR_clear_error();
  auto server = std::make_unique<httplib::SSLServer>([&](SSL_CTX& ctx) {
    SSL_CTX_set_min_proto_version(&ctx, TLS1_2_VERSION);
    SSL_CTX_set_options(&ctx, SSL_OP_NO_COMPRESSION | SSL_OP_NO_RENEGOTIATION);
    // An encrypted key fails instead of prompting for a pass phrase on the terminal.
    SSL_CTX_set_default_passwd_cb(&ctx, [](char*, int, int, void*) { return 0; });
    if (SSL_CTX_use_certificate_chain_file(&ctx, cert.c_str()) != 1) {
      failure = "TLS certificate " + cert + " is not a PEM certificate chain: " + openssl_error();
      return false;
    }
    if (SSL_CTX_use_PrivateKey_file(&ctx, key.c_str(), SSL_FILETYPE_PEM) != 1) {
      bool mismatch = false;
      const std::string detail = openssl_error(&mismatch);
      failure = "TLS private key " + key +
                (mismatch ? " does not match the certificate " + cert
                          : std::string(" is not an unencrypted PEM private key")) +
                ": " + detail;
      return false;
    }
    if (SSL_CTX_check_private_key(&ctx) != 1) {
      failure = "TLS private key " + key + " does not match the certificate " + cert + ": " +
                openssl_error();
      return false;
    }
    return true;
  });
  if (!server->is_valid()) {
    throw ValidationError(failure.empty() ? "TLS setup failed: " + openssl_error() : failure);
  }
  return server;
}

}  // namespace polmap::mapping
