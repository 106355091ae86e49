// `eyesim`: the host program. Sub-commands register themselves (see eyesim/app/command.hpp).
#include "eyesim/app/command.hpp"

#include <algorithm>
#include <cstdio>
#include <exception>
#include <map>
#include <string>

int main(int argc, char** argv) {
    using namespace eyesim::app;
    CLI::App app{"eyesim: FPGA marker tracking model, device protocol and eye-surgery tissue simulator"};
    app.require_subcommand(1);
    app.set_version_flag("--version", "eyesim 0.1.0");

    // Fixed order for the common commands, then any others alphabetically.
    static const char* const order[] = {"demo", "synth", "fpga", "track", "validate", "sim", "bench", "protocol"};
    auto rank = [](const std::string& n) {
        for (size_t i = 0; i < std::size(order); ++i)
            if (n == order[i]) return static_cast<int>(i);
        return static_cast<int>(std::size(order));
    };
    auto& specs = registry();
    std::stable_sort(specs.begin(), specs.end(), [&](const CommandSpec& a, const CommandSpec& b) {
        return rank(a.name) != rank(b.name) ? rank(a.name) < rank(b.name) : a.name < b.name;
    });

    std::map<CLI::App*, Action> actions;
    for (auto& spec : specs) {
        CLI::App* sub = app.add_subcommand(spec.name, spec.help);
        actions[sub] = spec.setup(*sub);
    }

    if (argc > 1 && argv[1][0] != '-' &&
        std::none_of(specs.begin(), specs.end(), [&](const CommandSpec& c) { return c.name == argv[1]; })) {
        std::string names;
        for (const auto& c : specs) names += (names.empty() ? "" : ", ") + c.name;
        std::fprintf(stderr, "eyesim: error: '%s': unknown command (commands: %s)\n", argv[1], names.c_str());
        return 2;
    }
    try {
        app.parse(argc, argv);
        for (auto& [sub, action] : actions)
            if (sub->parsed()) return action();
        return 2;
    } catch (const CLI::Success& e) {  // --help, --version
        return app.exit(e);
    } catch (const CLI::ParseError& e) {
        // Usage errors: one line, exit 2 (CLI11 would add a second line and its own exit codes).
        std::fprintf(stderr, "eyesim: error: %s (see --help)\n", e.what());
        return 2;
    } catch (const Error& e) {
        std::fprintf(stderr, "eyesim: error: %s\n", e.what());
        return e.exit_code();
    } catch (const std::exception& e) {
        std::fprintf(stderr, "eyesim: error: %s\n", e.what());
        return 1;
    }
}
