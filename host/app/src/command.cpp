#include "eyesim/app/command.hpp"

#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <filesystem>

namespace eyesim::app {

std::vector<CommandSpec>& registry() {
    static std::vector<CommandSpec> commands;  // function-local: safe from static-init order
    return commands;
}

Registrar::Registrar(std::string name, std::string help, Setup setup) {
    registry().push_back({std::move(name), std::move(help), std::move(setup)});
}

void add_report_delay_option(CLI::App& sub, double& report_delay_ms, double max_ms) {
    sub.add_option("--report-delay-ms", report_delay_ms,
                   "with --sync async: report each reference field's frame this long after its exposure, its poses "
                   "smoothed by the parts fused since (0: a frame at once from each part; at most " +
                       std::to_string(int(max_ms)) + ")")
        ->check(finite_in(0.0, max_ms))
        ->capture_default_str();
}

CLI::Validator finite_in(double lo, double hi) {
    return CLI::Validator(
        [lo, hi](std::string& text) -> std::string {
            double v = 0;
            if (!CLI::detail::lexical_cast(text, v) || !std::isfinite(v) || v < lo || v > hi)
                return "Value " + text + " not a finite number in [" + CLI::detail::to_string(lo) + ", " +
                       CLI::detail::to_string(hi) + "]";
            return {};
        },
        "FINITE in [" + CLI::detail::to_string(lo) + " - " + CLI::detail::to_string(hi) + "]");
}

CLI::Validator unsigned_integer() {
    return CLI::Validator(
        [](std::string& text) -> std::string {
            const bool digits = !text.empty() && text.size() <= 20 &&
                                std::all_of(text.begin(), text.end(), [](char c) { return c >= '0' && c <= '9'; });
            std::uint64_t v = 0;
            if (!digits || !CLI::detail::lexical_cast(text, v) || (text.size() == 20 && text > "18446744073709551615"))
                return "Value " + text + " not a whole number in [0, 18446744073709551615]";
            return {};
        },
        "UINT64");
}

bool show_progress(bool json) { return !json && ::isatty(STDERR_FILENO) == 1; }

std::string executable_dir() {
    std::error_code ec;
    const auto self = std::filesystem::read_symlink("/proc/self/exe", ec);
    return ec ? std::string(".") : self.parent_path().string();
}

}  // namespace eyesim::app
