// Accuracy against the rig's rendered truth (independent renderer with exact coverage, shading, noise) and the
// push_line copy path: rendered fields through the model must match the truth centroids.
#include "field_gen.hpp"
#include "rig_fixture.hpp"

#include "eyesim/rig/match.hpp"
#include "eyesim/rig/recording.hpp"
#include "eyesim/rig/synth.hpp"
#include "eyesim/rig/truth.hpp"
#include "eyesim/rig/video.hpp"

#include <catch2/catch.hpp>

#include <cmath>
#include <filesystem>

using namespace eyesim::fpga;
using namespace eyesim::fpga::test;
namespace rig = eyesim::rig;

TEST_CASE("rig recording: every visible marker found, centroid RMS within the documented bias", "[fpga][rig]") {
    RigRecording rr("eyesim_fpga_rig_test", "static", 0.1, 1.0);  // 5 fields × 3 cameras
    rig::Recording& rec = rr.rec;
    const std::vector<rig::FieldTruth>& truth = rr.truth;
    REQUIRE(truth.size() == 5);

    Pipeline p{RegisterMap{}};
    std::vector<uint8_t> field(static_cast<size_t>(rig::kFieldBytes));
    double se = 0, se_binary = 0;
    int matched = 0, missed = 0, extra = 0;
    RegisterMap bin_regs;
    bin_regs.write(reg::kWeightMode, 0);
    Pipeline pb(bin_regs);
    for (int64_t i = 0; i < 5; ++i) {
        for (int cam = 0; cam < rec.camera_count(); ++cam) {
            rec.read_field(cam, i, field.data());
            Field f(288);
            f.bytes = field;
            const std::vector<Blob> blobs = run_field(p, f), bblobs = run_field(pb, f);
            REQUIRE(blobs.size() == bblobs.size());
            std::vector<rig::DetectedMarker> det;
            for (const Blob& b : blobs) det.push_back({b.class_id, Eigen::Vector2d(b.cx_px(), b.cy_px())});
            std::vector<bool> used;
            rig::match_markers(
                truth[static_cast<size_t>(i)], cam, det, 3.0,
                [](const rig::MarkerTruth&, const rig::MarkerCameraTruth& v) { return v.visible && !(v.area_px < 4.0); },
                [&](const rig::MarkerMatch& m) {
                    if (m.detection < 0) {
                        ++missed;
                        return;
                    }
                    se += m.distance_px * m.distance_px;
                    // The binary pipeline finds the same blobs (same mask), in the same order.
                    const Blob& bb = bblobs[static_cast<size_t>(m.detection)];
                    se_binary += std::pow(bb.cx_px() - m.view->centroid_px.x(), 2) +
                                 std::pow(bb.cy_px() - m.view->centroid_px.y(), 2);
                    ++matched;
                },
                used);
            for (bool u : used) extra += !u;
        }
    }
    const double rms = std::sqrt(se / matched), rms_binary = std::sqrt(se_binary / matched);
    INFO("rms " << rms << " binary " << rms_binary << " matched " << matched);
    CHECK(matched > 100);
    CHECK(missed == 0);
    CHECK(extra == 0);
    CHECK(rms < 0.06);              // docs/bench/fpga-model.md: 0.04–0.045 px on rig recordings
    CHECK(rms * 2.5 < rms_binary);  // weighted centroids beat binary ones by a wide margin
}

TEST_CASE("push_line with a reused buffer equals process_field (edge ring line copy)", "[fpga][rig]") {
    std::mt19937 rng(8);
    std::uniform_real_distribution<double> ux(10, 710), uy(5, 283);
    std::vector<Marker> ms;
    for (int i = 0; i < 30; ++i) ms.push_back({1 + i % 4, ux(rng), uy(rng), 4.5, 2.25});
    const Field f = render_markers(ms, 1.0, 12);
    Pipeline a{RegisterMap{}}, b{RegisterMap{}};
    const std::vector<Blob> want = run_field(a, f);
    std::vector<Blob> got;
    b.set_sink([](void* c, const Blob& x) { static_cast<std::vector<Blob>*>(c)->push_back(x); }, &got);
    std::vector<uint8_t> line(kLineBytes);
    REQUIRE(b.begin_field(0, 0) == PipelineStatus::kOk);
    for (int y = 0; y < 288; ++y) {
        std::copy(f.line(y), f.line(y) + kLineBytes, line.begin());  // the caller's buffer is overwritten
        REQUIRE(b.push_line(line.data(), y) == PipelineStatus::kOk);
    }
    REQUIRE(b.end_field() == PipelineStatus::kOk);
    REQUIRE(b.field_stats().ring_pixels == a.field_stats().ring_pixels);
    REQUIRE(got.size() == want.size());
    std::sort(got.begin(), got.end(), [](const Blob& x, const Blob& y) {
        return std::tie(x.class_id, x.y_min, x.x_min) < std::tie(y.class_id, y.y_min, y.x_min);
    });
    for (size_t i = 0; i < got.size(); ++i) {
        CHECK(got[i].sum_w == want[i].sum_w);
        CHECK(got[i].sum_wxy == want[i].sum_wxy);
        CHECK(got[i].cx_q16 == want[i].cx_q16);
    }
}

TEST_CASE("MPEG-2 4:2:2 intra video (D-10 / IMX) keeps the centroids within 2x the raw fields' error, unbiased",
          "[fpga][rig][video]") {
    // The lossy format whose chroma is the camera's own 4:2:2: only the codec's quantisation is added. The same
    // 0.4 s sweep (20 fields × 3 cameras, seed 13) written as raw fields and as video, every visible marker of
    // ≥ 4 px scored against the rendered truth on both.
    REQUIRE(rig::encoder_available(rig::VideoCodec::kMpeg2_422));  // FFmpeg's own encoder, in every build
    struct Score {
        double se = 0, sx = 0, sy = 0, sy_parity[2] = {0, 0};
        int n = 0, n_parity[2] = {0, 0}, missed = 0;
    };
    auto score = [](const std::string& format) {
        RigRecording rr("eyesim_fpga_m422_" + format, "sweep", 0.4, 1.0, 13, format);
        rig::Recording& rec = rr.rec;
        const std::vector<rig::FieldTruth>& truth = rr.truth;
        Pipeline p{RegisterMap{}};
        std::vector<uint8_t> field(static_cast<size_t>(rig::kFieldBytes));
        Score s;
        for (int64_t i = 0; i < rec.common_field_count() && i < static_cast<int64_t>(truth.size()); ++i)
            for (int cam = 0; cam < rec.camera_count(); ++cam) {
                REQUIRE(rec.read_field(cam, i, field.data()));
                Field f(288);
                f.bytes = field;
                std::vector<rig::DetectedMarker> det;
                for (const Blob& b : run_field(p, f)) det.push_back({b.class_id, Eigen::Vector2d(b.cx_px(), b.cy_px())});
                std::vector<bool> used;
                const int parity = truth[static_cast<size_t>(i)].cameras[static_cast<size_t>(cam)].parity & 1;
                rig::match_markers(
                    truth[static_cast<size_t>(i)], cam, det, 3.0,
                    [](const rig::MarkerTruth&, const rig::MarkerCameraTruth& v) { return v.visible && !(v.area_px < 4.0); },
                    [&](const rig::MarkerMatch& m) {
                        if (m.detection < 0) {
                            ++s.missed;
                            return;
                        }
                        const Eigen::Vector2d d = det[static_cast<size_t>(m.detection)].centroid_px - m.view->centroid_px;
                        s.se += d.squaredNorm();
                        s.sx += d.x();
                        s.sy += d.y();
                        s.sy_parity[parity] += d.y();
                        ++s.n_parity[parity];
                        ++s.n;
                    },
                    used);
            }
        return s;
    };
    const Score raw = score("uyvy"), vid = score("mpeg2-422");
    const double rms_raw = std::sqrt(raw.se / raw.n), rms_vid = std::sqrt(vid.se / vid.n);
    INFO("raw " << rms_raw << " px (" << raw.n << "), video " << rms_vid << " px (" << vid.n << "), video bias x "
                << vid.sx / vid.n << " y " << vid.sy / vid.n << ", y by parity " << vid.sy_parity[0] / vid.n_parity[0]
                << " / " << vid.sy_parity[1] / vid.n_parity[1]);
    REQUIRE(raw.n > 300);
    CHECK(vid.n == raw.n);
    CHECK(vid.missed == raw.missed);
    CHECK(rms_vid > rms_raw);  // lossy: it does cost something
    CHECK(rms_vid < 2.0 * rms_raw);
    CHECK(std::abs(vid.sx / vid.n) < 0.01);
    CHECK(std::abs(vid.sy / vid.n) < 0.01);
}
