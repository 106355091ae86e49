#pragma once
// Running the programs a user runs from a test: a scratch folder per process (CTest runs test cases side by side
// as separate processes) removed at exit, and one command with a time limit, its stdout and stderr kept apart.
#include <sys/wait.h>
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <system_error>

namespace eyesim::test {

/// What one command did.
struct CliResult {
    int rc = -1;          ///< exit status (-1: killed or not run)
    std::string out, err; ///< its stdout and stderr
};

/// The whole file as a string.
inline std::string slurp(const std::filesystem::path& p) {
    std::ifstream in(p, std::ios::binary);
    return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

/// `<temp>/<name>_<pid>`, created empty, removed when the object goes.
class ScratchDir {
public:
    explicit ScratchDir(const std::string& name)
        : path_(std::filesystem::temp_directory_path() / (name + "_" + std::to_string(::getpid()))) {
        std::filesystem::remove_all(path_);
        std::filesystem::create_directories(path_);
    }
    ~ScratchDir() {
        std::error_code ec;
        std::filesystem::remove_all(path_, ec);
    }
    ScratchDir(const ScratchDir&) = delete;
    ScratchDir& operator=(const ScratchDir&) = delete;
    const std::filesystem::path& path() const { return path_; }

private:
    std::filesystem::path path_;
};

/// Runs `exe args` (shell words) under `timeout_s`, with stdout and stderr captured through files in `dir`.
inline CliResult run_cli(const std::filesystem::path& dir, const std::string& exe, const std::string& args,
                         int timeout_s) {
    const std::filesystem::path out = dir / "stdout.txt", err = dir / "stderr.txt";
    const std::string cmd =
        "timeout " + std::to_string(timeout_s) + " " + exe + " " + args + " >" + out.string() + " 2>" + err.string();
    const int status = std::system(cmd.c_str());
    CliResult r;
    r.rc = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
    r.out = slurp(out);
    r.err = slurp(err);
    return r;
}

}  // namespace eyesim::test
