#include "eyesim/frame/stage_timer.hpp"

#include <algorithm>
#include <numeric>

namespace eyesim::frame {

const char* to_string(Stage s) {
    switch (s) {
        case Stage::kTracking: return "tracking";
        case Stage::kCollision: return "collision";
        case Stage::kTissue: return "tissue";
        case Stage::kTransfer: return "geometry_transfer";
        case Stage::kMisc: return "misc";
        case Stage::kRender: return "render";
        case Stage::kCount: break;
    }
    return "?";
}

StageTimer::StageTimer(size_t frames) { rows_.reserve(frames); }

void StageTimer::begin_frame() { current_.fill(0.0); }

void StageTimer::end_frame() { rows_.push_back(current_); }

double percentile(std::vector<double> v, double pct) {
    if (v.empty()) return 0.0;
    std::sort(v.begin(), v.end());
    const double pos = std::clamp(pct, 0.0, 100.0) / 100.0 * double(v.size() - 1);
    const size_t i = size_t(pos);
    const double f = pos - double(i);
    return i + 1 < v.size() ? v[i] * (1.0 - f) + v[i + 1] * f : v[i];
}

namespace {
StageSummary summarise(const std::vector<double>& v) {
    StageSummary s;
    if (v.empty()) return s;
    s.p50_us = percentile(v, 50);
    s.p90_us = percentile(v, 90);
    s.p99_us = percentile(v, 99);
    s.max_us = *std::max_element(v.begin(), v.end());
    s.mean_us = std::accumulate(v.begin(), v.end(), 0.0) / double(v.size());
    return s;
}
}  // namespace

StageSummary StageTimer::summary(Stage st) const { return summary_of_sum({st}); }

StageSummary StageTimer::summary_where_ran(Stage st) const {
    std::vector<double> v;
    for (const auto& r : rows_)
        if (r[size_t(st)] > 0.0) v.push_back(r[size_t(st)]);
    return summarise(v);
}

StageSummary StageTimer::summary_of_sum(std::initializer_list<Stage> stages) const {
    std::vector<double> v;
    v.reserve(rows_.size());
    for (const auto& r : rows_) {
        double sum = 0;
        for (Stage s : stages) sum += r[size_t(s)];
        v.push_back(sum);
    }
    return summarise(v);
}

}  // namespace eyesim::frame
