#pragma once
/// \file
/// Collects the core's per-blob latency records (PC build) into storage reserved up front, and summarises them.

#include "eyesim/firmware/latency.hpp"

#include <cstddef>
#include <vector>

namespace eyesim::firmware::pc {

/// Percentiles of one latency component, µs.
struct LatencySummary {
    std::size_t count = 0;  ///< records summarised
    double p50_us = 0;      ///< median
    double p99_us = 0;      ///< 99th percentile (nearest rank)
    double max_us = 0;      ///< largest
    double mean_us = 0;     ///< mean
};

/// A LatencyObserver keeping at most `capacity` records (later ones are counted but not kept).
class LatencyLog final : public LatencyObserver {
public:
    /// Reserves room for `capacity` records.
    explicit LatencyLog(std::size_t capacity = 1u << 20);
    /// Keeps the record while there is reserved room.
    void on_blob(const BlobLatency& record) noexcept override;
    /// Records kept.
    const std::vector<BlobLatency>& records() const noexcept { return records_; }
    /// Records seen, kept or not.
    std::size_t seen() const noexcept { return seen_; }
    /// Forgets every record.
    void clear() noexcept { records_.clear(), seen_ = 0; }

    /// Which interval to summarise.
    enum class Span { last_pixel_to_complete, last_pixel_to_queued, last_pixel_to_written };
    /// Summary of one interval over the kept records (optionally only one mode: 0 per-field, 1 low-latency).
    LatencySummary summarise(Span span, int low_latency_only = -1) const;

private:
    std::vector<BlobLatency> records_;
    std::size_t seen_ = 0;
};

}  // namespace eyesim::firmware::pc
