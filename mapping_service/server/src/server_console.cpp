// The web console: GET / (web/console/index.html) and its assets under /console/, with
// MapLibre GL JS from web/console's npm lock file, all embedded into the binary at build time
// (.incbin), so the page works offline from this server alone. Served with the headers a
// console needs: a CSP without 'unsafe-inline' (MapLibre's worker is a blob: URL, hence
// worker-src blob:), no framing, no referrer, no sniffing.
#include <map>
#include <mutex>
#include <string>
#include <string_view>

#include "polmap/util/sha256.hpp"
#include "server_impl.hpp"

// Each asset: a read-only symbol pair <name>_begin / <name>_end around the file's bytes.
#define POLMAP_EMBED(name, path)                                                                 \
  asm(".section .rodata\n.global " #name "_begin\n.balign 16\n" #name "_begin:\n.incbin \"" path \
      "\"\n.global " #name "_end\n" #name "_end:\n.byte 0\n.previous\n");                        \
  extern "C" const char name##_begin[];                                                          \
  extern "C" const char name##_end[]

POLMAP_EMBED(polmap_console_index, POLMAP_CONSOLE_DIR "/index.html");
POLMAP_EMBED(polmap_console_js, POLMAP_CONSOLE_DIR "/console.js");
POLMAP_EMBED(polmap_console_css, POLMAP_CONSOLE_DIR "/console.css");
POLMAP_EMBED(polmap_maplibre_js, POLMAP_MAPLIBRE_DIR "/maplibre-gl.js");
POLMAP_EMBED(polmap_maplibre_css, POLMAP_MAPLIBRE_DIR "/maplibre-gl.css");
POLMAP_EMBED(polmap_maplibre_license, POLMAP_MAPLIBRE_DIR "/../LICENSE.txt");

namespace polmap::mapping {
namespace {

struct Asset {
  const char* path;
  const char* type;
  std::string_view bytes;
};

const Asset* find_asset(std::string_view path) {
  static const Asset assets[] = {
      {"/",
       "text/html; charset=utf-8",
       {polmap_console_index_begin,
        static_cast<std::size_t>(polmap_console_index_end - polmap_console_index_begin)}},
      {"/console/console.js",
       "text/javascript; charset=utf-8",
       {polmap_console_js_begin,
        static_cast<std::size_t>(polmap_console_js_end - polmap_console_js_begin)}},
      {"/console/console.css",
       "text/css; charset=utf-8",
       {polmap_console_css_begin,
        static_cast<std::size_t>(polmap_console_css_end - polmap_console_css_begin)}},
      {"/console/maplibre-gl.js",
       "text/javascript; charset=utf-8",
       {polmap_maplibre_js_begin,
        static_cast<std::size_t>(polmap_maplibre_js_end - polmap_maplibre_js_begin)}},
      {"/console/maplibre-gl.css",
       "text/css; charset=utf-8",
       {polmap_maplibre_css_begin,
        static_cast<std::size_t>(polmap_maplibre_css_end - polmap_maplibre_css_begin)}},
      {"/console/LICENSE-maplibre.txt",
       "text/plain; charset=utf-8",
       {polmap_maplibre_license_begin,
        static_cast<std::size_t>(polmap_maplibre_license_end - polmap_maplibre_license_begin)}},
  };
  for (const Asset& a : assets) {
    if (path == a.path) return &a;
  }
  return nullptr;
}

}  // namespace

/// The console's Content-Security-Policy (tests/web/console_test.mjs checks it).
constexpr const char* kConsoleCsp =
    "default-src 'none'; script-src 'self'; style-src 'self'; img-src 'self' data: blob:; "
    "connect-src 'self'; worker-src blob:; child-src blob:; font-src 'self'; base-uri 'none'; "
    "form-action 'none'; frame-ancestors 'none'";

void Server::Impl::register_console_routes() {
  auto serve = [this](const httplib::Request& req, httplib::Response& res) {
    set_route("console");
    const Asset* a = find_asset(req.path);
    if (a == nullptr) return reply_error(res, 404, "no such console file", "path");
    // Strong ETag of the embedded bytes (computed once per asset and process).
    static std::mutex mu;
    static std::map<const Asset*, std::string> etags;
    std::string etag;
    {
      std::lock_guard lock(mu);
      auto it = etags.find(a);
      if (it == etags.end()) {
        std::string quoted(1, '"');
        quoted += util::sha256_hex(a->bytes);
        quoted += '"';
        it = etags.emplace(a, std::move(quoted)).first;
      }
      etag = it->second;
    }
    res.set_header("Content-Security-Policy", kConsoleCsp);
    res.set_header("X-Content-Type-Options", "nosniff");
    res.set_header("Referrer-Policy", "no-referrer");
    res.set_header("X-Frame-Options", "DENY");
    res.set_header("Cross-Origin-Opener-Policy", "same-origin");
    res.set_header("ETag", etag);
    // The page is revalidated every time (a new server version brings new assets).
    res.set_header("Cache-Control", "no-cache");
    if (req.get_header_value("If-None-Match") == etag) {
      res.status = 304;
      return;
    }
    res.status = 200;
    res.set_content(std::string(a->bytes), a->type);
  };
  http.Get("/", serve);
  http.Get(R"(/console/([A-Za-z0-9._-]+))", serve);
}

}  // namespace polmap::mapping
