#pragma once
/// @file command.hpp
/// Self-registration of `polmap` subcommands: each cmd_*.cpp defines a setup
/// function that adds its subcommand to the app, and registers it with
/// POLMAP_REGISTER_COMMAND. Commands report failures by throwing polmap::Error
/// (one-line message, exit code 1) or by calling set_exit_code().
#include <CLI/CLI.hpp>
#include <functional>
#include <string>
#include <vector>

namespace polmap::cli {

using SetupFn = void (*)(CLI::App& app);

struct CommandEntry {
  std::string name;
  SetupFn setup;
};

std::vector<CommandEntry>& command_registry();

struct RegisterCommand {
  RegisterCommand(const char* name, SetupFn fn) { command_registry().push_back({name, fn}); }
};

/// Exit code the process returns after a command callback ran (default 0).
void set_exit_code(int code);
int exit_code();

}  // namespace polmap::cli

#define POLMAP_REGISTER_COMMAND(name, fn) \
  static const ::polmap::cli::RegisterCommand polmap_register_##name(#name, fn)
