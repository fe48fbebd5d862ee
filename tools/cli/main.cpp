// polmap: one CLI with subcommands (see `polmap --help`).
#include <CLI/CLI.hpp>
#include <cstdio>
#include <exception>

#include "command.hpp"
#include "polmap/schema/errors.hpp"

namespace polmap::cli {
std::vector<CommandEntry>& command_registry() {
  static std::vector<CommandEntry> registry;
  return registry;
}
namespace {
int g_exit_code = 0;
}
void set_exit_code(int code) { g_exit_code = code; }
int exit_code() { return g_exit_code; }
}  // namespace polmap::cli

int main(int argc, char** argv) {
  CLI::App app{"polmap: radar landmark maps from a vehicle fleet, and localization against them"};
  app.set_version_flag("--version", "polmap 0.1.0");
  app.require_subcommand(1);
  app.failure_message([](const CLI::App*, const CLI::Error& e) {
    return std::string(e.what()) + " (see --help)\n";
  });
  auto& registry = polmap::cli::command_registry();
  std::sort(registry.begin(), registry.end(),
            [](const auto& a, const auto& b) { return a.name < b.name; });
  for (const auto& entry : registry) entry.setup(app);
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    if (e.get_exit_code() != 0) std::fputs("polmap: error: ", stderr);
    return app.exit(e);
  } catch (const polmap::ContractViolation& e) {
    // A bug of ours, not bad input: its own exit code, so scripts can tell them apart.
    std::fprintf(stderr, "polmap: internal error (contract violated, please report): %s\n",
                 e.what());
    return 3;
  } catch (const polmap::Error& e) {
    std::fprintf(stderr, "polmap: error: %s\n", e.what());
    return 1;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "polmap: internal error: %s\n", e.what());
    return 2;
  }
  return polmap::cli::exit_code();
}
