// `polmap build-map --server URL --api-key KEY [--exclude-drive ID]... [--region BBOX]
//  [--notes TEXT] [--wait]`: starts a map build on the mapping service (POST /v1/maps)
// and prints the new map version on stdout; with --wait, polls until the build is
// published (or fails: exit code 1 with the server's error).
#include <CLI/CLI.hpp>
#include <chrono>
#include <cstdio>
#include <memory>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "command.hpp"
#include "polmap/schema/errors.hpp"
#include "progress.hpp"

// Last: httplib pulls in <resolv.h>, whose `_res` macro breaks Eigen templates.
#include "http_client.hpp"

namespace polmap::cli {
namespace {

struct BuildMapOptions {
  std::string server;
  std::string api_key;
  std::vector<std::string> exclude;
  std::string region;
  std::string notes;
  bool wait = false;
  double wait_timeout_s = 3600;
  bool json = false;
};

std::vector<double> parse_region(const std::string& s) {
  std::vector<double> v;
  std::stringstream ss(s);
  std::string item;
  while (std::getline(ss, item, ',')) {
    try {
      std::size_t used = 0;
      v.push_back(std::stod(item, &used));
      if (used != item.size()) throw std::invalid_argument(item);
    } catch (const std::exception&) {
      throw ValidationError("--region '" + s + "': '" + item + "' is not a number");
    }
  }
  if (v.size() != 4)
    throw ValidationError("--region '" + s + "': expected minlon,minlat,maxlon,maxlat");
  return v;
}

void run(const BuildMapOptions& o) {
  nlohmann::json body{{"exclude_drives", o.exclude}};
  if (!o.region.empty()) body["region"] = parse_region(o.region);
  if (!o.notes.empty()) body["notes"] = o.notes;
  auto cli = make_client(o.server, 60);
  httplib::Headers headers{{"Authorization", "Bearer " + o.api_key}};
  const auto r = cli->Post("/v1/maps", headers, body.dump(), "application/json");
  const auto& res = expect_ok(r, o.server, "map build");
  const auto started = nlohmann::json::parse(res.body);
  const std::int64_t version = started.at("version").get<std::int64_t>();
  if (!o.wait) {
    if (o.json) {
      std::printf("%s\n", res.body.c_str());
    } else {
      std::printf("%lld\n", static_cast<long long>(version));
    }
    return;
  }
  const auto t0 = std::chrono::steady_clock::now();
  Progress progress("building map version " + std::to_string(version), 0);
  for (;;) {
    const auto g = cli->Get("/v1/maps/" + std::to_string(version));
    const auto& info = expect_ok(g, o.server, "map version " + std::to_string(version));
    const auto j = nlohmann::json::parse(info.body);
    const std::string status = j.value("status", "");
    if (status == "published") {
      progress.finish();
      if (o.json) {
        std::printf("%s\n", info.body.c_str());
      } else {
        std::printf("%lld\n", static_cast<long long>(version));
      }
      return;
    }
    if (status != "building") {
      progress.finish();
      throw Error("map version " + std::to_string(version) + " " + status + ": " +
                  j.value("error", std::string("no reason given")));
    }
    const double waited =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    if (waited > o.wait_timeout_s) {
      throw Error("map version " + std::to_string(version) + " still building after " +
                  std::to_string(static_cast<int>(waited)) + " s (--wait-timeout-s)");
    }
    progress.update(waited, "s");
    std::this_thread::sleep_for(std::chrono::milliseconds(250));
  }
}

void setup(CLI::App& app) {
  auto opts = std::make_shared<BuildMapOptions>();
  CLI::App* cmd = app.add_subcommand(
      "build-map", "Build a new map version on the mapping service; prints the version");
  cmd->add_option("--server", opts->server, "Service URL, e.g. http://127.0.0.1:8080")->required();
  cmd->add_option("--api-key", opts->api_key, "API key (Bearer token) for writes")
      ->required()
      ->envname("POLMAP_API_KEY");
  cmd->add_option("--exclude-drive", opts->exclude, "Drive id to leave out (repeatable)");
  cmd->add_option("--region", opts->region, "Restrict to minlon,minlat,maxlon,maxlat (degrees)");
  cmd->add_option("--notes", opts->notes, "Free text stored with the version");
  cmd->add_flag("--wait", opts->wait, "Wait until the version is published");
  cmd->add_option("--wait-timeout-s", opts->wait_timeout_s, "Give up waiting after this long")
      ->capture_default_str();
  cmd->add_flag("--json", opts->json, "Print the server's JSON instead of the version number");
  cmd->callback([opts] { run(*opts); });
}

}  // namespace
POLMAP_REGISTER_COMMAND(build_map, setup);
}  // namespace polmap::cli
