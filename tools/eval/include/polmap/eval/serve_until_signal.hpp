#pragma once
/// @file serve_until_signal.hpp
/// Runs a mapping::Server until SIGINT or SIGTERM, for the processes that host one
/// (`polmap serve`, bench_tile_server): the stop signals are blocked in every thread and
/// one watcher thread waits for them and stops the server (requests in flight finish).
#include <signal.h>

#include <functional>
#include <string>

#include "polmap/mapping_service/server.hpp"

namespace polmap::eval {

/// Blocks SIGINT and SIGTERM in the calling thread, and so in every thread it starts
/// afterwards (the server's threads inherit the mask), and returns that set for
/// listen_until_signal. Call it before starting any thread.
[[nodiscard]] sigset_t block_stop_signals();

/// server.listen(host, port) while a watcher thread waits for one of `signals` (blocked by
/// block_stop_signals), then calls on_signal(signal) if set and server.stop(). Returns when
/// listen() returns; what listen() throws is rethrown once the watcher has ended.
void listen_until_signal(mapping::Server& server, const sigset_t& signals, const std::string& host,
                         int port, const std::function<void(int)>& on_signal = {});

}  // namespace polmap::eval
