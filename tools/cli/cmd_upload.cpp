// `polmap upload --server URL --package PKG --api-key KEY [--json]`: uploads one drive
// package (a package directory, packed on the fly into the canonical ustar archive, or a
// .tar file) to the mapping service: POST /v1/drives.
#include <CLI/CLI.hpp>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <memory>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>

#include "command.hpp"
#include "polmap/mapping_service/drive_package_io.hpp"
#include "polmap/schema/errors.hpp"

// Last: httplib pulls in <resolv.h>, whose `_res` macro breaks Eigen templates.
#include "http_client.hpp"

namespace polmap::cli {
namespace {

struct UploadOptions {
  std::string server;
  std::string package;
  std::string api_key;
  int timeout_s = 600;
  bool json = false;
};

std::string read_file(const std::filesystem::path& p) {
  std::ifstream in(p, std::ios::binary);
  if (!in) throw IoError("cannot read " + p.string());
  std::ostringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

void run(const UploadOptions& o) {
  const std::filesystem::path pkg(o.package);
  std::string body;
  if (std::filesystem::is_directory(pkg)) {
    body = mapping::pack_drive_package(pkg);
  } else if (std::filesystem::is_regular_file(pkg)) {
    body = read_file(pkg);
  } else {
    throw IoError("--package " + o.package + ": no such directory or file");
  }
  auto cli = make_client(o.server, o.timeout_s);
  httplib::Headers headers{{"Authorization", "Bearer " + o.api_key}};
  const auto r = cli->Post("/v1/drives", headers, body, "application/x-tar");
  const auto& res = expect_ok(r, o.server, "upload of " + o.package);
  if (o.json) {
    std::printf("%s\n", res.body.c_str());
    return;
  }
  std::string id = "?";
  try {
    id = nlohmann::json::parse(res.body).value("drive_id", "?");
  } catch (const std::exception&) {
  }
  std::printf("drive %s %s (%zu bytes)\n", id.c_str(),
              res.status == 201 ? "uploaded" : "already present, not changed", body.size());
}

void setup(CLI::App& app) {
  auto opts = std::make_shared<UploadOptions>();
  CLI::App* cmd = app.add_subcommand("upload", "Upload a drive package to the mapping service");
  cmd->add_option("--server", opts->server, "Service URL, e.g. http://127.0.0.1:8080")->required();
  cmd->add_option("--package", opts->package, "Package directory or .tar archive")->required();
  cmd->add_option("--api-key", opts->api_key, "API key (Bearer token) for writes")
      ->required()
      ->envname("POLMAP_API_KEY");
  cmd->add_option("--timeout-s", opts->timeout_s, "Read/write timeout")->capture_default_str();
  cmd->add_flag("--json", opts->json, "Print the server's JSON answer");
  cmd->callback([opts] { run(*opts); });
}

}  // namespace
POLMAP_REGISTER_COMMAND(upload, setup);
}  // namespace polmap::cli
