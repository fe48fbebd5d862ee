// report_localization_run (run_reporter.hpp).
#include "polmap/localization_client/run_reporter.hpp"

#include <nlohmann/json.hpp>

// After everything that includes Eigen: httplib pulls in <resolv.h>, whose `_res` macro
// breaks Eigen's templates.
#include <httplib.h>

namespace polmap::loc {

RunReportResult report_localization_run(const std::string& server_url, const std::string& api_key,
                                        const LocalizationRun& run, double timeout_s) {
  RunReportResult out;
  std::string origin = server_url;
  while (!origin.empty() && origin.back() == '/') origin.pop_back();
  if (!origin.starts_with("http://") && !origin.starts_with("https://")) {
    out.message = "server URL must start with http:// or https://: " + server_url;
    return out;
  }
  httplib::Client client(origin);
  const auto us = static_cast<time_t>(timeout_s * 1e6);
  client.set_connection_timeout(0, std::min<time_t>(us, 10'000'000));
  client.set_read_timeout(0, us);
  client.set_write_timeout(0, us);
  if (origin.starts_with("https://")) client.enable_server_certificate_verification(true);
  const std::string body = encode_localization_run(run);
  const httplib::Headers headers{{"Authorization", "Bearer " + api_key}};
  const auto res = client.Post("/v1/runs", headers, body, "application/json");
  if (!res) {
    out.message = "no answer from " + origin + ": " + httplib::to_string(res.error());
    return out;
  }
  out.http_status = res->status;
  const auto j = nlohmann::json::parse(res->body, nullptr, false);
  if (res->status == 201) {
    out.status = RunReportResult::Status::Stored;
    if (j.is_object() && j.contains("id") && j["id"].is_number_integer()) {
      out.id = j["id"].get<std::int64_t>();
    }
    return out;
  }
  out.status = RunReportResult::Status::Refused;
  out.message = "HTTP " + std::to_string(res->status);
  if (j.is_object() && j.contains("error") && j["error"].is_string()) {
    out.message += ": " + j["error"].get<std::string>();
    if (j.contains("field") && j["field"].is_string()) {
      out.message += " (field '" + j["field"].get<std::string>() + "')";
    }
  }
  return out;
}

}  // namespace polmap::loc
