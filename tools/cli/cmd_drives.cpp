// `polmap drives --server URL [--json]`: lists the drives stored on the mapping service;
// `polmap drives --server URL --delete ID --api-key KEY` removes one.
#include <CLI/CLI.hpp>
#include <cctype>
#include <cstdio>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>

#include "command.hpp"
#include "polmap/schema/errors.hpp"

// Last: httplib pulls in <resolv.h>, whose `_res` macro breaks Eigen templates.
#include "http_client.hpp"

namespace polmap::cli {
namespace {

struct DrivesOptions {
  std::string server;
  std::string api_key;
  std::string del;
  bool json = false;
};

void run(const DrivesOptions& o) {
  auto cli = make_client(o.server, 60);
  if (!o.del.empty()) {
    httplib::Headers headers{{"Authorization", "Bearer " + o.api_key}};
    const auto r = cli->Delete("/v1/drives/" + percent_encode(o.del), headers);
    expect_ok(r, o.server, "delete drive " + o.del);
    std::printf("drive %s deleted\n", o.del.c_str());
    return;
  }
  const auto r = cli->Get("/v1/drives", {{"Authorization", "Bearer " + o.api_key}});
  const auto& res = expect_ok(r, o.server, "list drives");
  if (o.json) {
    std::printf("%s\n", res.body.c_str());
    return;
  }
  const auto j = nlohmann::json::parse(res.body);
  std::printf("%-24s %-12s %10s %8s %8s  %s\n", "drive_id", "vehicle", "distance_m", "points",
              "lines", "ingested_at");
  for (const auto& d : j.at("drives")) {
    std::printf("%-24s %-12s %10.1f %8lld %8lld  %s\n", d.value("drive_id", "").c_str(),
                d.value("vehicle_id", "").c_str(), d.value("distance_m", 0.0),
                static_cast<long long>(d.value("num_points", 0)),
                static_cast<long long>(d.value("num_lines", 0)),
                d.value("ingested_at", "").c_str());
  }
}

void setup(CLI::App& app) {
  auto opts = std::make_shared<DrivesOptions>();
  CLI::App* cmd = app.add_subcommand("drives", "List (or delete) drives on the mapping service");
  cmd->add_option("--server", opts->server, "Service URL, e.g. http://127.0.0.1:8080")->required();
  cmd->add_option("--delete", opts->del, "Delete this drive id (needs --api-key)");
  cmd->add_option("--api-key", opts->api_key, "API key (Bearer token) for writes")
      ->envname("POLMAP_API_KEY");
  cmd->add_flag("--json", opts->json, "Print the server's JSON");
  cmd->callback([opts] {
    if (!opts->del.empty() && opts->api_key.empty()) {
      throw ValidationError("--delete needs --api-key (or POLMAP_API_KEY)");
    }
    run(*opts);
  });
}

}  // namespace
POLMAP_REGISTER_COMMAND(drives, setup);
}  // namespace polmap::cli
