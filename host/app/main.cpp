// `eyesim`: the host program. Sub-commands register themselves (see eyesim/app/command.hpp).
#include "eyesim/app/command.hpp"

#include <algorithm>
#include <cstdio>
#include <exception>
#include <map>

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

    try {
        app.parse(argc, argv);
        for (auto& [sub, action] : actions)
            if (sub->parsed()) return action();
        return 2;
    } catch (const CLI::ParseError& e) {
        return app.exit(e);
    } catch (const Error& e) {
        std::fprintf(stderr, "eyesim: error: %s\n", e.what());
        return e.exit_code();
    } catch (const std::exception& e) {
        std::fprintf(stderr, "eyesim: error: %s\n", e.what());
        return 1;
    }
}
