// The fair OpenCV peer of the benchmarks (bench/fpga-model/opencv_peer.hpp) held to correctness: it must find
// every marker of synthetic fields with the generator's coverage centroids as truth, report nothing else, and
// follow the register map's class definitions.
#include "field_gen.hpp"
#include "opencv_peer.hpp"

#include <catch2/catch.hpp>

#include <cmath>

using namespace eyesim::fpga;
using namespace eyesim::fpga::test;
using eyesim::fpga::bench::Detection;
using eyesim::fpga::bench::OpenCvPeer;

namespace {

struct Score {
    int matched = 0, missed = 0, extra = 0;
    double se = 0, worst = 0;
    double rms() const { return matched ? std::sqrt(se / matched) : 1e9; }
};

// Class + nearest detection within 3 px for every marker; unmatched detections are extra.
void score(const std::vector<Marker>& markers, const std::vector<std::array<double, 2>>& truth,
           const std::vector<Detection>& det, Score& s) {
    std::vector<bool> used(det.size(), false);
    for (size_t i = 0; i < markers.size(); ++i) {
        int best = -1;
        double bd = 3.0;
        for (size_t j = 0; j < det.size(); ++j) {
            const double d = std::hypot(det[j].x - truth[i][0], det[j].y - truth[i][1]);
            if (!used[j] && det[j].cls == markers[i].cls && d < bd) {
                bd = d;
                best = static_cast<int>(j);
            }
        }
        if (best < 0) {
            ++s.missed;
            continue;
        }
        used[static_cast<size_t>(best)] = true;
        ++s.matched;
        s.se += bd * bd;
        s.worst = std::max(s.worst, bd);
    }
    for (bool u : used) s.extra += !u;
}

// Markers of every class and of 6–12 px (frame px; half as tall in a field) on a grid with random sub-pixel
// offsets, apart enough that their rings never touch.
std::vector<Marker> grid_markers(uint32_t seed) {
    std::mt19937 rng(seed);
    std::uniform_real_distribution<double> jitter(-3.0, 3.0), diam(6.0, 12.0);
    std::vector<Marker> ms;
    int i = 0;
    for (int gy = 0; gy < 4; ++gy)
        for (int gx = 0; gx < 6; ++gx, ++i) {
            const double d = diam(rng);
            ms.push_back({1 + i % 4, 60.0 + 120.0 * gx + jitter(rng), 36.0 + 72.0 * gy + jitter(rng) / 2, d / 2, d / 4});
        }
    return ms;
}

}  // namespace

TEST_CASE("OpenCV peer: every marker, nothing else, sub-0.05 px centroids", "[fpga][peer]") {
    OpenCvPeer peer;
    SECTION("noise-free fields, dark and white backgrounds: each marker within 0.05 px") {
        for (const std::array<double, 3> bg : {std::array<double, 3>{14, 14, 18}, std::array<double, 3>{236, 234, 226}}) {
            for (uint32_t seed = 1; seed <= 2; ++seed) {
                const std::vector<Marker> ms = grid_markers(seed);
                std::vector<std::array<double, 2>> truth;
                const Field f = render_markers(ms, 0.0, seed, 288, 8, bg, &truth);
                Score s;
                score(ms, truth, peer.run(f.bytes.data(), 288), s);
                INFO("background " << bg[0] << ", seed " << seed << ": worst " << s.worst << " px, rms " << s.rms());
                CHECK(s.matched == static_cast<int>(ms.size()));
                CHECK(s.extra == 0);
                CHECK(s.worst <= 0.05);
            }
        }
    }
    SECTION("noise sigma 1: every marker found, RMS within 0.05 px") {
        Score s;
        for (uint32_t seed = 3; seed <= 6; ++seed) {
            const std::vector<Marker> ms = grid_markers(seed);
            std::vector<std::array<double, 2>> truth;
            const Field f = render_markers(ms, 1.0, seed, 288, 8, {14, 14, 18}, &truth);
            score(ms, truth, peer.run(f.bytes.data(), 288), s);
        }
        INFO("rms " << s.rms() << " px, worst " << s.worst);
        CHECK(s.missed == 0);
        CHECK(s.extra == 0);
        CHECK(s.rms() <= 0.05);
    }
}

TEST_CASE("OpenCV peer: classes follow the register map", "[fpga][peer]") {
    const std::vector<Marker> ms = grid_markers(7);
    std::vector<std::array<double, 2>> truth;
    const Field f = render_markers(ms, 0.0, 7, 288, 8, {14, 14, 18}, &truth);
    auto count = [&](const RegisterMap& regs, int cls) {
        OpenCvPeer peer(regs);
        int n = 0;
        for (const Detection& d : peer.run(f.bytes.data(), 288)) n += d.cls == cls;
        return n;
    };
    int green = 0;
    for (const Marker& m : ms) green += m.cls == 2;
    RegisterMap reset;
    CHECK(count(reset, 2) == green);
    RegisterMap no_green;
    REQUIRE(no_green.write(reg::kClassEnable, 0xDu) == RegWriteResult::kOk);  // class 2 off
    CHECK(count(no_green, 2) == 0);
    CHECK(count(no_green, 1) == count(reset, 1));
    RegisterMap bright_green;  // a luma band above the green markers' luma (Y ≈ 132)
    REQUIRE(bright_green.write(reg::class_luma(2), 0xFFC8u) == RegWriteResult::kOk);
    CHECK(count(bright_green, 2) == 0);
}
