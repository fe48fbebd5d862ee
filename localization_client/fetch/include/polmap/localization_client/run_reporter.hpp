#pragma once
/// @file run_reporter.hpp
/// Sends a localization run report (schema/localization_run.hpp, built with RunRecorder) to
/// the mapping service: POST /v1/runs with a vehicle key. One attempt; the caller decides
/// about retries (a report is small and not urgent).
#include <cstdint>
#include <string>

#include "polmap/schema/localization_run.hpp"

namespace polmap::loc {

struct RunReportResult {
  enum class Status {
    Stored,          ///< 201: the server kept it as run `id`
    Refused,         ///< the server answered an error (http_status, message)
    TransportError,  ///< no answer (message says why)
  };
  Status status = Status::TransportError;
  int http_status = 0;
  std::int64_t id = 0;
  std::string message;
};

/// POSTs `run` to `server_url` (http://HOST:PORT or https://HOST:PORT) + /v1/runs with
/// `api_key` as Bearer token. Never throws for network or server errors.
[[nodiscard]] RunReportResult report_localization_run(const std::string& server_url,
                                                      const std::string& api_key,
                                                      const LocalizationRun& run,
                                                      double timeout_s = 30.0);

}  // namespace polmap::loc
