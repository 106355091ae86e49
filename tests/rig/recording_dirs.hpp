#pragma once
// Scratch recording directories for the rig tests: a fresh folder per test program, copies, and the check that
// opening a directory fails with one line naming the problem.
#include "eyesim/rig/error.hpp"
#include "eyesim/rig/recording.hpp"

#include <catch2/catch.hpp>

#include <unistd.h>

#include <cstdint>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

namespace rigtest {

namespace fs = std::filesystem;

/// An empty folder under the temporary directory, unique to this process.
inline std::string temp_dir(const std::string& name) {
    const fs::path p = fs::temp_directory_path() / ("eyesim_test_rec_" + name + "_" + std::to_string(::getpid()));
    fs::remove_all(p);
    fs::create_directories(p);
    return p.string();
}

/// `n` bytes of a file from `offset`.
inline std::vector<uint8_t> file_bytes(const std::string& path, size_t offset, size_t n) {
    std::ifstream in(path, std::ios::binary);
    in.seekg(static_cast<std::streamoff>(offset));
    std::vector<uint8_t> b(n);
    in.read(reinterpret_cast<char*>(b.data()), static_cast<std::streamsize>(n));
    return b;
}

/// Removes a directory when the test program exits.
struct RemoveAtExit {
    std::string dir;
    ~RemoveAtExit() {
        std::error_code ec;
        fs::remove_all(dir, ec);
    }
};

/// Replaces `to` by a copy of `from`.
inline void copy_dir(const std::string& from, const std::string& to) {
    fs::remove_all(to);
    fs::copy(from, to, fs::copy_options::recursive);
}

/// Opening `dir` throws RigError, one line containing `needle`.
inline void expect_open_error(const std::string& dir, const std::string& needle) {
    try {
        eyesim::rig::Recording::open(dir);
        FAIL("no error, expected " << needle);
    } catch (const eyesim::rig::RigError& e) {
        const std::string what = e.what();
        INFO(what);
        CHECK(what.find(needle) != std::string::npos);
        CHECK(what.find('\n') == std::string::npos);
    }
}

}  // namespace rigtest
