#pragma once
/// \file
/// In-process transport pair for tests: two connected endpoints over bounded byte pipes (one each way).
/// A writer that finds its pipe full waits up to its timeout (like a full socket buffer); closing either end
/// makes the other read `closed` once its pipe is drained.

#include "eyesim/transport/transport.hpp"

#include <cstddef>
#include <memory>
#include <utility>

namespace eyesim::transport {

/// Creates two connected endpoints; bytes written to `first` are read from `second` and the other way round.
/// Each direction buffers at most `capacity_bytes`.
std::pair<std::unique_ptr<Transport>, std::unique_ptr<Transport>> make_inproc_pair(std::size_t capacity_bytes = 1u << 16);

}  // namespace eyesim::transport
