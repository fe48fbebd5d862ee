#include "polmap/eval/serve_until_signal.hpp"

#include <pthread.h>

#include <atomic>
#include <ctime>
#include <thread>

namespace polmap::eval {

sigset_t block_stop_signals() {
  sigset_t signals;
  sigemptyset(&signals);
  sigaddset(&signals, SIGINT);
  sigaddset(&signals, SIGTERM);
  pthread_sigmask(SIG_BLOCK, &signals, nullptr);
  return signals;
}

void listen_until_signal(mapping::Server& server, const sigset_t& signals, const std::string& host,
                         int port, const std::function<void(int)>& on_signal) {
  std::atomic<bool> done{false};
  std::thread waiter([&] {
    const timespec tick{0, 200'000'000};
    while (!done) {
      const int sig = sigtimedwait(&signals, nullptr, &tick);
      if (sig == SIGINT || sig == SIGTERM) {
        if (on_signal) on_signal(sig);
        server.stop();
        return;
      }
    }
  });
  try {
    server.listen(host, port);
  } catch (...) {
    done = true;
    waiter.join();
    throw;
  }
  done = true;
  waiter.join();
}

}  // namespace polmap::eval
