#pragma once
/// \file
/// The single exception type of the rig library: a one-line message naming file, key and value at fault.

#include <stdexcept>
#include <string>

namespace eyesim::rig {

/// Bad input (missing or malformed file, wrong size, NaN, truncated data). `what()` is one line of the form
/// "<file>: <key or field>: <why>" so the `eyesim` program can print it as it is.
class RigError : public std::runtime_error {
public:
    explicit RigError(const std::string& what) : std::runtime_error(what) {}
};

}  // namespace eyesim::rig
