// Per-blob latency records and their percentiles.
#include "eyesim/firmware/pc/latency_log.hpp"

#include <algorithm>
#include <cmath>

namespace eyesim::firmware::pc {

LatencyLog::LatencyLog(std::size_t capacity) { records_.reserve(capacity); }

void LatencyLog::on_blob(const BlobLatency& record) noexcept {
    ++seen_;
    if (records_.size() < records_.capacity()) records_.push_back(record);
}

LatencySummary LatencyLog::summarise(Span span, int low_latency_only) const {
    std::vector<double> v;
    v.reserve(records_.size());
    for (const auto& r : records_) {
        if (low_latency_only >= 0 && r.low_latency != low_latency_only) continue;
        const std::uint64_t end = span == Span::last_pixel_to_complete ? r.complete_ns
                                  : span == Span::last_pixel_to_queued ? r.queued_ns
                                                                       : r.written_ns;
        v.push_back(static_cast<double>(end - r.last_pixel_ns) / 1000.0);
    }
    LatencySummary s;
    s.count = v.size();
    if (v.empty()) return s;
    std::sort(v.begin(), v.end());
    const auto rank = [&](double q) {
        const auto i = static_cast<std::size_t>(std::ceil(q * static_cast<double>(v.size()))) - 1;
        return v[std::min(i, v.size() - 1)];
    };
    s.p50_us = rank(0.50);
    s.p99_us = rank(0.99);
    s.max_us = v.back();
    double sum = 0;
    for (double x : v) sum += x;
    s.mean_us = sum / static_cast<double>(v.size());
    return s;
}

}  // namespace eyesim::firmware::pc
