// The fit's model of a 4:2:0 source's vertical chroma chain (SphereFitConfig::chroma_chain) against the video
// writer and reader it stands for: random chroma written as interlaced 4:2:0 and read back field by field must be
// the chain's taps applied to the fields written, to the rounding of the two integer stages.
#include "field_gen.hpp"
#include "rig_fixture.hpp"

#include "eyesim/fpga/pipeline.hpp"
#include "eyesim/rig/bodies.hpp"
#include "eyesim/rig/match.hpp"
#include "eyesim/rig/recording.hpp"
#include "eyesim/rig/video.hpp"
#include "eyesim/tracking/refine.hpp"

#include <catch2/catch.hpp>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include <unistd.h>

using namespace eyesim;
namespace fs = std::filesystem;

tracking::SphereFitConfig rig_config();  // test_refine.cpp: the fit with the rig's marker colours

namespace {

// Fields whose chroma is random down the lines and across them (every even pixel its own sample), luma flat.
std::vector<std::vector<uint8_t>> random_chroma_fields(int n, uint32_t seed) {
    std::mt19937 rng(seed);
    std::uniform_int_distribution<int> level(40, 216);
    std::vector<std::vector<uint8_t>> fields(static_cast<size_t>(n), std::vector<uint8_t>(rig::kFieldBytes));
    for (auto& f : fields)
        for (int y = 0; y < rig::kFieldHeight; ++y)
            for (int x = 0; x < rig::kFieldWidth; x += 2) {
                uint8_t* px = f.data() + (static_cast<size_t>(y) * rig::kFieldWidth + x) * 2;
                px[0] = static_cast<uint8_t>(level(rng));
                px[2] = static_cast<uint8_t>(level(rng));
                px[1] = px[3] = 100;
            }
    return fields;
}

struct ChainError {
    double rms_chain = 0, max_chain = 0;  // the chain's taps against what was read
    double rms_none = 0;                  // each line's own chroma (the 4:2:2 model) against what was read
    // The vertical chain on the eight lines at each edge of the field: with its edge taps, and with the interior
    // taps, the lines beyond the field taken as the edge line (4:2:0 only).
    double rms_edge = 0, max_edge = 0, rms_edge_interior = 0;
};

// Writes `fields` with `codec` (`chroma` for FFV1), reads each back, and compares every chroma sample of the
// lines away from the field's edges with the chain's prediction from the fields written.
ChainError chain_error(rig::VideoCodec codec, rig::VideoChroma chroma, const std::vector<std::vector<uint8_t>>& fields) {
    // One directory per codec, chroma and process: ctest runs the test cases side by side.
    const std::string dir = (fs::temp_directory_path() / ("eyesim_chain_" + std::string(rig::to_string(codec)) + "_" +
                                                         std::to_string(static_cast<int>(chroma)) + "_" +
                                                         std::to_string(::getpid())))
                                .string();
    fs::create_directories(dir);
    const std::string path = dir + "/v" + rig::extension(codec);
    {
        rig::VideoWriter w(path, codec, rig::FieldOrder::kTopFirst, chroma);
        for (size_t i = 0; i + 1 < fields.size(); i += 2) w.write(fields[i].data(), fields[i + 1].data());
        w.close();
    }
    rig::VideoReader r(path);
    const bool across = r.info().chroma == "4:1:1";  // the chain across the columns, else down the lines
    REQUIRE((across || r.info().chroma == "4:2:0"));
    tracking::SphereFitConfig cfg;
    if (across) {
        tracking::chroma_chain_411(cfg, rig::chroma_column_site(r.info()));
        REQUIRE(cfg.chroma_chain_h);
        for (int ph = 0; ph < 2; ++ph) {
            double sum = 0;
            for (double t : cfg.chroma_h_taps[ph]) sum += t;
            CHECK(sum == Approx(1.0).margin(1e-12));
        }
    } else {
        double site[2][2];
        for (int p = 0; p < 2; ++p)
            for (int c = 0; c < 2; ++c) site[p][c] = rig::field_chroma_site(r.info(), p, c);
        tracking::chroma_chain_420(cfg, site, rig::kFieldHeight);
        REQUIRE(cfg.chroma_chain);
        REQUIRE(cfg.chroma_chain_field_lines == rig::kFieldHeight);
        for (int p = 0; p < 2; ++p)
            for (int ph = 0; ph < 2; ++ph)
                for (int c = 0; c < 2; ++c) {
                    double sum = 0;
                    for (double t : cfg.chroma_v_taps[p][ph][c]) sum += t;
                    CHECK(sum == Approx(1.0).margin(1e-12));
                }
    }
    ChainError e;
    double se_chain = 0, se_none = 0, se_edge = 0, se_edge_interior = 0;
    long n = 0, n_edge = 0;
    std::vector<uint8_t> out(rig::kFieldBytes);
    constexpr int kL = tracking::kChromaChainLines;
    for (size_t i = 0; i < fields.size(); ++i) {
        std::string why;
        REQUIRE(r.load_frame(static_cast<int64_t>(i / 2), why) == rig::FrameStatus::kOk);
        const int parity = static_cast<int>(i % 2);
        r.extract_field(parity, true, out.data());
        const std::vector<uint8_t>& in = fields[i];
        for (int y = 8; y < rig::kFieldHeight - 8; ++y)
            for (int x = 16; x < rig::kFieldWidth - 16; x += 2)
                for (int c = 0; c < 2; ++c) {
                    const int byte = c == 0 ? 0 : 2;
                    auto at = [&](const std::vector<uint8_t>& f, int line, int col) {
                        return double(f[(static_cast<size_t>(line) * rig::kFieldWidth + col) * 2 + byte]);
                    };
                    double pred = 0;
                    if (across) {
                        const double* taps = cfg.chroma_h_taps[(x / 2) & 1];
                        for (int d = -kL; d <= kL; ++d) pred += taps[d + kL] * at(in, y, x + 2 * d);
                    } else {
                        const double* taps = cfg.chroma_v_taps[parity][y & 1][c];
                        for (int d = -kL; d <= kL; ++d) pred += taps[d + kL] * at(in, y + d, x);
                    }
                    const double got = at(out, y, x), err = got - pred;
                    se_chain += err * err;
                    e.max_chain = std::max(e.max_chain, std::abs(err));
                    se_none += (got - at(in, y, x)) * (got - at(in, y, x));
                    ++n;
                }
        for (int y = 0; !across && y < rig::kFieldHeight; y = y == 7 ? rig::kFieldHeight - 8 : y + 1)
            for (int x = 16; x < rig::kFieldWidth - 16; x += 2)
                for (int c = 0; c < 2; ++c) {
                    const int byte = c == 0 ? 0 : 2;
                    auto at = [&](const std::vector<uint8_t>& f, int line) {
                        line = std::clamp(line, 0, rig::kFieldHeight - 1);
                        return double(f[(static_cast<size_t>(line) * rig::kFieldWidth + x) * 2 + byte]);
                    };
                    const double* taps = tracking::chroma_chain_v_taps(cfg, parity, y, c, rig::kFieldHeight);
                    const double* inner = cfg.chroma_v_taps[parity][y & 1][c];
                    double pred = 0, pred_inner = 0, sum = 0;
                    for (int d = -kL; d <= kL; ++d) {
                        // The edge taps reach no line beyond the field.
                        if (y + d < 0 || y + d >= rig::kFieldHeight) CHECK(taps[d + kL] == 0.0);
                        pred += taps[d + kL] * at(in, y + d);
                        pred_inner += inner[d + kL] * at(in, y + d);
                        sum += taps[d + kL];
                    }
                    CHECK(sum == Approx(1.0).margin(1e-12));
                    const double got = at(out, y);
                    se_edge += (got - pred) * (got - pred);
                    se_edge_interior += (got - pred_inner) * (got - pred_inner);
                    e.max_edge = std::max(e.max_edge, std::abs(got - pred));
                    ++n_edge;
                }
    }
    fs::remove_all(dir);
    e.rms_chain = std::sqrt(se_chain / static_cast<double>(n));
    e.rms_none = std::sqrt(se_none / static_cast<double>(n));
    if (n_edge > 0) {
        e.rms_edge = std::sqrt(se_edge / static_cast<double>(n_edge));
        e.rms_edge_interior = std::sqrt(se_edge_interior / static_cast<double>(n_edge));
    }
    return e;
}

}  // namespace

namespace {

// Random chroma through lossless FFV1 holding `chroma`'s planes: only the chain and its two roundings (the writer's
// to whole DN, the reader's weights in 1/256) remain.
void check_lossless_chain(rig::VideoChroma chroma, uint32_t seed, const char* what) {
    const ChainError lossless = chain_error(rig::VideoCodec::kFfv1, chroma, random_chroma_fields(6, seed));
    INFO(what << ": chain RMS " << lossless.rms_chain << " DN (max " << lossless.max_chain << "), without the chain "
              << lossless.rms_none << " DN");
    CHECK(lossless.rms_chain < 0.6);
    CHECK(lossless.max_chain <= 1.5);
    CHECK(lossless.rms_none > 20.0);  // random chroma: the 4:2:2 model is far off
    if (chroma == rig::VideoChroma::k420) {
        // The field's first and last eight lines, where the writer repeats the edge line and the reader the edge row.
        INFO(what << " at the field's edges: edge taps RMS " << lossless.rms_edge << " DN (max " << lossless.max_edge
                  << "), interior taps " << lossless.rms_edge_interior << " DN");
        CHECK(lossless.rms_edge < 0.6);
        CHECK(lossless.max_edge <= 1.5);
        CHECK(lossless.rms_edge_interior > 4.0 * lossless.rms_edge);
    }
}

}  // namespace

TEST_CASE("the fit's 4:2:0 chroma chain is the writer's decimation and the reader's interpolation, line by line",
          "[tracking][refine][video]") {
    // MPEG-2 / H.264 siting: a quarter line into each field.
    check_lossless_chain(rig::VideoChroma::k420, 11, "FFV1 4:2:0");
}

TEST_CASE("the fit's 4:1:1 chroma chain is the writer's decimation and the reader's interpolation, sample by sample",
          "[tracking][refine][video]") {
    // DVCPRO25's siting (co-sited with every fourth pixel), lossless; then DVCPRO25 itself, whose quantisation stays
    // on top of the chain.
    check_lossless_chain(rig::VideoChroma::k411, 12, "FFV1 4:1:1");
    // DVCPRO25: chroma random across the columns and the same down them (the codec's error in one direction only).
    std::mt19937 rng(7);
    std::uniform_int_distribution<int> level(70, 186);
    std::vector<std::vector<uint8_t>> columns(4, std::vector<uint8_t>(rig::kFieldBytes));
    for (auto& f : columns) {
        std::vector<uint8_t> cb(rig::kFieldWidth / 2), cr(rig::kFieldWidth / 2);
        for (size_t k = 0; k < cb.size(); ++k) {
            cb[k] = static_cast<uint8_t>(level(rng));
            cr[k] = static_cast<uint8_t>(level(rng));
        }
        for (int y = 0; y < rig::kFieldHeight; ++y)
            for (int x = 0; x < rig::kFieldWidth; x += 2) {
                uint8_t* px = f.data() + (static_cast<size_t>(y) * rig::kFieldWidth + x) * 2;
                px[0] = cb[static_cast<size_t>(x / 2)];
                px[2] = cr[static_cast<size_t>(x / 2)];
                px[1] = px[3] = 100;
            }
    }
    const ChainError dv411 = chain_error(rig::VideoCodec::kDv411, rig::VideoChroma::kCodec, columns);
    INFO("DVCPRO25: chain RMS " << dv411.rms_chain << " DN, per-sample model " << dv411.rms_none << " DN");
    CHECK(dv411.rms_chain < 0.5 * dv411.rms_none);
}

TEST_CASE("DV's line-alternate 4:2:0 chain: Cr on the even field lines, Cb on the odd", "[tracking][refine][video]") {
    // DV is lossy: its quantisation stays on top of the chain. Chroma random down the lines and the same across
    // them puts the codec's error in one direction only; the chain must still explain most of what was read.
    std::mt19937 rng(5);
    std::uniform_int_distribution<int> level(70, 186);
    std::vector<std::vector<uint8_t>> fields(4, std::vector<uint8_t>(rig::kFieldBytes));
    for (auto& f : fields)
        for (int y = 0; y < rig::kFieldHeight; ++y) {
            const auto cb = static_cast<uint8_t>(level(rng)), cr = static_cast<uint8_t>(level(rng));
            for (int x = 0; x < rig::kFieldWidth; x += 2) {
                uint8_t* px = f.data() + (static_cast<size_t>(y) * rig::kFieldWidth + x) * 2;
                px[0] = cb;
                px[2] = cr;
                px[1] = px[3] = 100;
            }
        }
    const ChainError dv = chain_error(rig::VideoCodec::kDv, rig::VideoChroma::kCodec, fields);
    INFO("DV: chain RMS " << dv.rms_chain << " DN, per-line model " << dv.rms_none << " DN; at the field's edges "
                          << dv.rms_edge << " DN, with the interior taps " << dv.rms_edge_interior << " DN");
    CHECK(dv.rms_chain < 0.5 * dv.rms_none);
    CHECK(dv.rms_edge < 0.5 * dv.rms_edge_interior);
}

TEST_CASE("sphere fit on lossless 4:2:0 and 4:1:1 video: the chain's model of the chroma places clear markers closer",
          "[tracking][rig][refine][video]") {
    // FFV1 holding 4:2:0 or 4:1:1 planes (synth --format ffv1-420 / ffv1-411): what subsampling alone costs. Without
    // the chain the fit can only down-weight the chroma it cannot follow (sphere_fit_config_for_source: σ 8 DN),
    // leaving the position to the luma; with it, the chroma is modelled as read and weighted as the sensor's.
    const std::string format = GENERATE(std::string("ffv1-420"), std::string("ffv1-411"));
    const bool is411 = format == "ffv1-411";
    fpga::test::RigRecording written("eyesim_chain_fit_" + format, "surgery", 0.4, 1.0, 3, format);  // 20 fields, σ 1
    rig::Recording& rec = written.rec;
    REQUIRE(rec.format(0) == rig::StreamFormat::kVideo);
    const rig::VideoInfo info = rig::VideoReader(rec.stream_path(0)).info();
    REQUIRE(info.chroma == (is411 ? "4:1:1" : "4:2:0"));
    const tracking::SphereFitConfig without =
        tracking::sphere_fit_config_for_source(rig_config(), info.chroma.c_str(), true);
    tracking::SphereFitConfig with = without;
    if (is411) {
        CHECK(rig::chroma_column_site(info) == 0.0);  // DVCPRO25's siting: co-sited with every fourth pixel
        tracking::chroma_chain_411(with, rig::chroma_column_site(info));
    } else {
        double site[2][2];
        for (int p = 0; p < 2; ++p)
            for (int c = 0; c < 2; ++c) site[p][c] = rig::field_chroma_site(info, p, c);
        CHECK(site[0][0] == 0.25);  // MPEG-2 / H.264 siting, a quarter line into each field
        CHECK(site[1][1] == 0.75);
        tracking::chroma_chain_420(with, site, rig::kFieldHeight);
    }
    CHECK(with.chain_chroma_noise_dn == with.noise_dn);

    auto work = std::make_unique<tracking::SphereFitWorkspace>();
    fpga::Pipeline p{fpga::RegisterMap{}};
    fpga::test::Field f(rig::kFieldHeight);
    double se[2] = {0, 0}, se_both[2] = {0, 0};
    int matched = 0, refined[2] = {0, 0}, both = 0;
    for (int64_t i = 0; i < 20; ++i)
        for (int cam = 0; cam < rec.camera_count(); ++cam) {
            rec.read_field(cam, i, f.bytes.data());
            const std::vector<fpga::Blob> blobs = fpga::test::run_field(p, f);
            std::vector<rig::DetectedMarker> det;
            std::vector<tracking::SphereFitResult> fits[2];
            for (const fpga::Blob& b : blobs) {
                det.push_back({b.class_id, Eigen::Vector2d(b.cx_px(), b.cy_px())});
                fits[0].push_back(tracking::fit_sphere(f.bytes.data(), f.height, tracking::blob_box(b), without, *work));
                fits[1].push_back(tracking::fit_sphere(f.bytes.data(), f.height, tracking::blob_box(b), with, *work));
            }
            std::vector<bool> used;
            rig::match_markers(
                written.truth[static_cast<size_t>(i)], cam, det, 3.0,
                [](const rig::MarkerTruth&, const rig::MarkerCameraTruth& v) {
                    return v.visible && !(v.area_px < 2.0) && !(v.occluded_fraction > 0.0);
                },
                [&](const rig::MarkerMatch& m) {
                    if (m.detection < 0) return;
                    const size_t d = static_cast<size_t>(m.detection);
                    const Eigen::Vector2d t = m.view->centroid_px;
                    const Eigen::Vector2d pipeline(blobs[d].cx_px(), blobs[d].cy_px());
                    for (int k = 0; k < 2; ++k) {
                        const tracking::SphereFitResult& r = fits[k][d];
                        const Eigen::Vector2d at = r.ok ? Eigen::Vector2d(r.cx_px, r.cy_px) : pipeline;
                        se[k] += (at - t).squaredNorm();
                        refined[k] += r.ok;
                    }
                    if (fits[0][d].ok && fits[1][d].ok) {
                        ++both;
                        for (int k = 0; k < 2; ++k)
                            se_both[k] += (Eigen::Vector2d(fits[k][d].cx_px, fits[k][d].cy_px) - t).squaredNorm();
                    }
                    ++matched;
                },
                used);
        }
    REQUIRE(matched > 150);
    REQUIRE(both > 100);
    const double rms[2] = {std::sqrt(se[0] / matched), std::sqrt(se[1] / matched)};
    const double rms_both[2] = {std::sqrt(se_both[0] / both), std::sqrt(se_both[1] / both)};
    INFO("clear markers " << matched << ": refined without the chain " << refined[0] << ", with " << refined[1]
                          << "; RMS " << rms[0] << " -> " << rms[1] << " px; on the " << both << " both fitted "
                          << rms_both[0] << " -> " << rms_both[1]);
    // The chain's χ² also refuses a few fits the down-weighted chroma let through off the mark (seed 3, 4:2:0: 7 of
    // 228, 0.0167 → 0.0133 px over all; 4:1:1: 8, 0.0139 → 0.0121); where both fit, the chain's are closer (0.0135 →
    // 0.0125, 0.0140 → 0.0112).
    CHECK(refined[1] > 0.9 * matched);
    CHECK(rms[1] < 0.9 * rms[0]);
    CHECK(rms_both[1] < 0.95 * rms_both[0]);
}
