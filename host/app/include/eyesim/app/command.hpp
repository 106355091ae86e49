#pragma once
/// \file
/// Sub-command registry of the `eyesim` program. Each `host/app/cmd_*.cpp` registers one sub-command with a
/// static `Registrar`, so adding a command never touches main.cpp.

#include <CLI/CLI.hpp>

#include <functional>
#include <stdexcept>
#include <string>
#include <vector>

namespace eyesim::app {

/// What a sub-command does once its options are parsed; returns the process exit code.
using Action = std::function<int()>;

/// Declares a sub-command's options on `sub` and returns the action to run when it is chosen.
using Setup = std::function<Action(CLI::App& sub)>;

/// One registered sub-command.
struct CommandSpec {
    std::string name;  ///< e.g. "fpga"
    std::string help;  ///< one line for `eyesim --help`
    Setup setup;
};

/// All sub-commands registered so far (static-initialisation safe).
std::vector<CommandSpec>& registry();

/// Registers a sub-command at static-initialisation time: `static Registrar reg{"fpga", "…", setup};`.
struct Registrar {
    Registrar(std::string name, std::string help, Setup setup);
};

/// A user-facing failure: main prints `eyesim: error: <what>` on one line and exits with `exit_code`.
/// Name the file, field and value at fault in the message.
class Error : public std::runtime_error {
public:
    explicit Error(const std::string& what, int exit_code = 1) : std::runtime_error(what), exit_code_(exit_code) {}
    int exit_code() const noexcept { return exit_code_; }

private:
    int exit_code_;
};

/// CLI validator: a finite number in [lo, hi]. (CLI::Range lets "nan" through: every comparison with NaN is false.)
CLI::Validator finite_in(double lo, double hi);

/// CLI validator: a whole number in 0..2^64 - 1, for unsigned options such as seeds. (CLI11 reads "-1" into an
/// unsigned option as 2^64 - 1 without a word.)
CLI::Validator unsigned_integer();

/// `--report-delay-ms` (tracking::AsyncOptions::report_delay_us, at most `max_ms`) on a command that tracks with
/// `--sync async`.
void add_report_delay_option(CLI::App& sub, double& report_delay_ms, double max_ms);

/// True when progress lines should go to stderr: stderr is a terminal and `--json` was not given.
bool show_progress(bool json);

/// Path of the running executable's folder (to find `eyesim-device` beside `eyesim`).
std::string executable_dir();

}  // namespace eyesim::app
