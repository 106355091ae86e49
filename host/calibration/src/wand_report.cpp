// `eyesim calibrate`'s JSON summary and HTML report.
#include "eyesim/calibration/wand_report.hpp"

#include <Eigen/Geometry>
#include <fmt/format.h>
#include <fmt/ranges.h>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>

namespace eyesim::calibration {

namespace {

constexpr double kPi = 3.14159265358979323846;

double rms(const std::vector<double>& v) {
    double s = 0;
    for (double x : v) s += x * x;
    return v.empty() ? 0.0 : std::sqrt(s / static_cast<double>(v.size()));
}
double mean(const std::vector<double>& v) {
    double s = 0;
    for (double x : v) s += x;
    return v.empty() ? 0.0 : s / static_cast<double>(v.size());
}

std::string html_escape(const std::string& s) {
    std::string o;
    for (char c : s) {
        if (c == '<') o += "&lt;";
        else if (c == '>') o += "&gt;";
        else if (c == '&') o += "&amp;";
        else o += c;
    }
    return o;
}

void put(cv::Mat& img, const std::string& text, cv::Point at, double scale = 0.42) {
    cv::putText(img, text, at, cv::FONT_HERSHEY_SIMPLEX, scale, cv::Scalar(30, 30, 30), 1, cv::LINE_AA);
}

/// Histogram of one or more series over [lo, hi] (values outside are counted at the ends and said so).
void histogram(const std::string& path, const std::string& title, const std::string& xlabel, double lo, double hi,
               const std::vector<std::pair<std::string, std::vector<double>>>& series) {
    const int W = 640, H = 320, L = 60, R = 20, T = 40, B = 50, bins = 41;
    cv::Mat img(H, W, CV_8UC3, cv::Scalar(255, 255, 255));
    std::vector<std::vector<int>> counts(series.size(), std::vector<int>(bins, 0));
    int top = 1;
    size_t clipped = 0;
    for (size_t s = 0; s < series.size(); ++s)
        for (double v : series[s].second) {
            clipped += v < lo || v > hi;
            const int b = std::clamp(static_cast<int>((v - lo) / (hi - lo) * bins), 0, bins - 1);
            top = std::max(top, ++counts[s][static_cast<size_t>(b)]);
        }
    const cv::Scalar ink(30, 30, 30), grid(225, 225, 225);
    cv::rectangle(img, {L, T}, {W - R, H - B}, ink, 1);
    for (int k = 0; k <= 4; ++k) {
        const double v = lo + (hi - lo) * k / 4.0;
        const int x = L + (W - L - R) * k / 4;
        cv::line(img, {x, T}, {x, H - B}, grid, 1);
        const std::string label = fmt::format("{:.3g}", v);
        int base = 0;
        const int w = cv::getTextSize(label, cv::FONT_HERSHEY_SIMPLEX, 0.42, 1, &base).width;
        put(img, label, {std::clamp(x - w / 2, 2, W - w - 2), H - B + 16});
    }
    put(img, title, {L, 22}, 0.5);
    put(img, xlabel, {W / 2 - 40, H - 12});
    put(img, fmt::format("max {} per bin", top), {5, T - 6}, 0.38);
    if (clipped) put(img, fmt::format("{} values outside, counted at the ends", clipped), {L + 5, T + 16}, 0.38);
    static const cv::Scalar colours[] = {{180, 90, 20}, {30, 120, 230}, {40, 160, 40}};
    const double bw = static_cast<double>(W - L - R) / bins;
    for (size_t s = 0; s < series.size(); ++s) {
        const cv::Scalar c = colours[s % 3];
        std::vector<cv::Point> pts;
        for (int b = 0; b < bins; ++b) {
            const int y = H - B - static_cast<int>(static_cast<double>(H - T - B) * counts[s][static_cast<size_t>(b)] / top);
            pts.emplace_back(L + static_cast<int>(b * bw), y);
            pts.emplace_back(L + static_cast<int>((b + 1) * bw), y);
        }
        cv::polylines(img, pts, false, c, 2, cv::LINE_AA);
        cv::line(img, {W - R - 150, T + 14 + 16 * static_cast<int>(s)}, {W - R - 130, T + 14 + 16 * static_cast<int>(s)}, c, 2);
        put(img, series[s].first, {W - R - 125, T + 18 + 16 * static_cast<int>(s)}, 0.4);
    }
    cv::imwrite(path, img);
}

/// The camera's frame at half size with the 16 × 12 coverage grid (cells with a wand marker shaded) and the
/// marker observations as dots.
void coverage_picture(const std::string& path, const WandCameraStats& st, const rig::CameraModel& cam) {
    const int W = cam.image_width / 2, H = cam.image_height / 2;
    cv::Mat img(H, W, CV_8UC3, cv::Scalar(40, 40, 40));
    constexpr int gx = 16, gy = 12;
    std::vector<bool> hit(gx * gy, false);
    for (const auto& p : st.observed_px) {
        const int x = std::clamp(static_cast<int>(p.x() / cam.image_width * gx), 0, gx - 1);
        const int y = std::clamp(static_cast<int>(p.y() / cam.image_height * gy), 0, gy - 1);
        hit[static_cast<size_t>(y * gx + x)] = true;
    }
    for (int y = 0; y < gy; ++y)
        for (int x = 0; x < gx; ++x)
            if (hit[static_cast<size_t>(y * gx + x)])
                cv::rectangle(img, {x * W / gx, y * H / gy}, {(x + 1) * W / gx - 1, (y + 1) * H / gy - 1},
                              cv::Scalar(70, 90, 70), cv::FILLED);
    for (int x = 0; x <= gx; ++x) cv::line(img, {x * W / gx, 0}, {x * W / gx, H}, cv::Scalar(80, 80, 80), 1);
    for (int y = 0; y <= gy; ++y) cv::line(img, {0, y * H / gy}, {W, y * H / gy}, cv::Scalar(80, 80, 80), 1);
    const size_t step = std::max<size_t>(1, st.observed_px.size() / 6000);
    for (size_t i = 0; i < st.observed_px.size(); i += step) {
        const auto& p = st.observed_px[i];
        cv::circle(img, {static_cast<int>(p.x() / 2), static_cast<int>(p.y() / 2)}, 1, cv::Scalar(80, 220, 90), cv::FILLED);
    }
    cv::putText(img, fmt::format("{:.0f} % of the image", 100.0 * st.coverage), {6, H - 8}, cv::FONT_HERSHEY_SIMPLEX,
                0.45, cv::Scalar(240, 240, 240), 1, cv::LINE_AA);
    cv::imwrite(path, img);
}

nlohmann::json or_null(bool ok, double v) { return ok ? nlohmann::json(v) : nlohmann::json(nullptr); }

}  // namespace

std::vector<CameraTruthError> compare_with_truth(const std::vector<rig::CameraModel>& cal,
                                                 const std::vector<rig::CameraModel>& truth, const rig::EyeBody& eye) {
    if (cal.size() != truth.size())
        throw CalibrationError(fmt::format("the true rig has {} cameras, the calibrated one {}", truth.size(), cal.size()));
    std::vector<CameraTruthError> out;
    for (size_t c = 0; c < cal.size(); ++c) {
        CameraTruthError e;
        e.centre_error_um = (cal[c].center_rig_mm() - truth[c].center_rig_mm()).norm() * 1e3;
        e.rotation_error_deg = Eigen::AngleAxisd(cal[c].R_cam_rig * truth[c].R_cam_rig.transpose()).angle() * 180.0 / kPi;
        e.fx_error_pct = (cal[c].fx - truth[c].fx) / truth[c].fx * 100.0;
        e.fy_error_pct = (cal[c].fy - truth[c].fy) / truth[c].fy * 100.0;
        e.time_offset_error_us = cal[c].field_time_offset_us - truth[c].field_time_offset_us;
        double se = 0, mx = 0;
        int64_t n = 0;
        for (double x = -30; x <= 30; x += 2)
            for (double y = -30; y <= 30; y += 2)
                for (double z = -20; z <= 35; z += 2) {
                    const Eigen::Vector3d X = eye.center_rig_mm + Eigen::Vector3d(x, y, z);
                    if (Eigen::Vector3d(x, y, z).norm() <= eye.radius_mm) continue;
                    const auto pt = truth[c].project_frame(X);
                    if (!pt || pt->x() < 0 || pt->y() < 0 || pt->x() > truth[c].image_width - 1 ||
                        pt->y() > truth[c].image_height - 1)
                        continue;
                    const auto pc = cal[c].project_frame(X);
                    if (!pc) continue;
                    const double d = (*pc - *pt).norm();
                    se += d * d;
                    mx = std::max(mx, d);
                    ++n;
                }
        e.projection_error_px_rms = n ? std::sqrt(se / static_cast<double>(n)) : 0.0;
        e.projection_error_px_max = mx;
        out.push_back(e);
    }
    return out;
}

nlohmann::json summary_json(const CalibrationSummary& s) {
    nlohmann::json j;
    j["out"] = s.out;
    j["wand"] = s.wand_dir;
    j["board"] = s.board_dir.empty() ? nlohmann::json(nullptr) : nlohmann::json(s.board_dir);
    j["intrinsics"] = s.intrinsics_file.empty() ? nlohmann::json("board") : nlohmann::json(s.intrinsics_file);
    j["fields"] = s.fields;
    j["samples"] = s.solve.samples;
    j["detect_s"] = s.detect_s;
    j["solve_s"] = s.solve.solve_s;
    j["iterations"] = s.solve.iterations;
    j["converged"] = s.solve.converged;
    j["final_cost"] = s.solve.final_cost;
    const auto& wl = s.solve.wand_length_error_mm;
    j["wand_length_error_mm"] = wl.empty() ? nlohmann::json(nullptr)
                                           : nlohmann::json{{"mean", mean(wl)}, {"rms", rms(wl)}, {"samples", wl.size()}};
    j["rig_frame"] = {{"eye_markers", s.rig_frame.markers},
                      {"views", s.rig_frame.views},
                      {"views_dropped", s.rig_frame.views_dropped},
                      {"marker_ids", s.rig_frame.marker_ids},
                      {"residual_mm_rms", s.rig_frame.residual_mm_rms},
                      {"residual_px_rms", s.rig_frame.residual_px_rms}};
    nlohmann::json cams = nlohmann::json::array();
    for (size_t c = 0; c < s.cameras.size(); ++c) {
        const WandCameraStats& st = s.solve.stats.at(c);
        nlohmann::json rej;
        for (int r = 1; r < static_cast<int>(WandReject::kCount); ++r)
            rej[to_string(static_cast<WandReject>(r))] = s.views.rejects.at(c)[static_cast<size_t>(r)];
        const bool any = st.observations > 0;
        nlohmann::json cj{{"camera", c},
                          {"views", st.views},
                          {"rejected", rej},
                          {"jumps", st.jumps},
                          {"samples", st.samples},
                          {"observations", st.observations},
                          {"outliers", st.outliers},
                          {"image_error_px_rms", or_null(any, st.image_error_px_rms)},
                          {"image_error_frame_px_rms", or_null(any, st.image_error_frame_px_rms)},
                          {"world_error_mm", or_null(any, st.world_error_mm)},
                          {"time_offset_us", st.time_offset_us},
                          {"field_time_offset_us", s.cameras[c].field_time_offset_us},
                          {"coverage", st.coverage},
                          {"fx", s.cameras[c].fx},
                          {"fy", s.cameras[c].fy}};
        if (c < s.board.size() && s.board[c])
            cj["board"] = {{"rms_px", s.board[c]->rms_px}, {"views", s.board[c]->views_used}, {"coverage", s.board[c]->coverage}};
        if (c < s.truth.size()) {
            const CameraTruthError& e = s.truth[c];
            cj["truth"] = {{"centre_error_um", e.centre_error_um},
                           {"rotation_error_deg", e.rotation_error_deg},
                           {"fx_error_pct", e.fx_error_pct},
                           {"fy_error_pct", e.fy_error_pct},
                           {"time_offset_error_us", e.time_offset_error_us},
                           {"projection_error_px_rms", e.projection_error_px_rms},
                           {"projection_error_px_max", e.projection_error_px_max}};
        }
        cams.push_back(cj);
    }
    j["cameras"] = cams;
    if (!s.truth.empty()) {
        double centre = 0, rot = 0, focal = 0, proj = 0;
        for (const auto& e : s.truth) {
            centre = std::max(centre, e.centre_error_um);
            rot = std::max(rot, e.rotation_error_deg);
            focal = std::max({focal, std::fabs(e.fx_error_pct), std::fabs(e.fy_error_pct)});
            proj = std::max(proj, e.projection_error_px_rms);
        }
        j["truth"] = {{"rig", s.truth_file},
                      {"worst_centre_error_um", centre},
                      {"worst_rotation_error_deg", rot},
                      {"worst_focal_error_pct", focal},
                      {"worst_projection_error_px_rms", proj}};
    }
    j["notes"] = s.solve.notes;
    j["warnings"] = s.warnings;
    j["errors"] = 0;
    return j;
}

std::string write_report(const std::string& dir, const CalibrationSummary& s) {
    namespace fs = std::filesystem;
    std::error_code ec;
    fs::create_directories(dir, ec);
    if (ec || !fs::is_directory(dir)) throw CalibrationError(fmt::format("{}: cannot create report folder", dir));
    const size_t nc = s.cameras.size();
    // Pictures.
    for (size_t c = 0; c < nc; ++c) {
        const WandCameraStats& st = s.solve.stats.at(c);
        std::vector<double> rx, ry;
        for (const auto& r : st.residual_px) {
            rx.push_back(r.x());
            ry.push_back(r.y());
        }
        std::vector<double> all = rx;
        all.insert(all.end(), ry.begin(), ry.end());
        for (double& v : all) v = std::fabs(v);
        std::sort(all.begin(), all.end());
        double span = all.empty() ? 0.1 : all[std::min(all.size() - 1, static_cast<size_t>(0.995 * static_cast<double>(all.size())))] * 1.2;
        span = std::max(span, 1e-3);
        histogram(fmt::format("{}/residuals_cam{}.png", dir, c),
                  fmt::format("cam{}: wand reprojection residuals (observed - projected)", c), "field px", -span, span,
                  {{"x", rx}, {"y", ry}});
        coverage_picture(fmt::format("{}/coverage_cam{}.png", dir, c), st, s.cameras[c]);
    }
    if (!s.solve.wand_length_error_mm.empty()) {
        std::vector<double> um;
        for (double e : s.solve.wand_length_error_mm) um.push_back(e * 1e3);
        std::vector<double> a = um;
        for (double& v : a) v = std::fabs(v);
        std::sort(a.begin(), a.end());
        const double span = std::max(1.0, a[std::min(a.size() - 1, static_cast<size_t>(0.995 * static_cast<double>(a.size())))] * 1.2);
        histogram(dir + "/wand_length.png", "Wand length (end markers triangulated freely) - known length", "um",
                  -span, span, {{"samples", um}});
    }

    std::ofstream h(dir + "/index.html");
    if (!h) throw CalibrationError(fmt::format("{}/index.html: cannot write", dir));
    const std::string title = "eyesim calibrate: " + s.out;
    h << "<!doctype html><html><head><meta charset='utf-8'><title>" << html_escape(title) << "</title>"
      << "<style>body{font-family:sans-serif;max-width:1100px;margin:2em auto;color:#222}"
         "table{border-collapse:collapse}td,th{border:1px solid #ccc;padding:4px 10px;text-align:right}"
         "th{background:#f0f0f0}td:first-child{text-align:left}img{max-width:100%}</style></head><body>\n";
    h << "<h1>" << html_escape(title) << "</h1>\n";
    h << "<p>Wand recording <b>" << html_escape(s.wand_dir) << "</b>, " << s.fields << " fields per camera; intrinsics "
      << (s.board_dir.empty() ? "from <b>" + html_escape(s.intrinsics_file) + "</b>"
                              : "calibrated from the board recording <b>" + html_escape(s.board_dir) + "</b>")
      << ". " << s.solve.samples << " wand samples in the bundle adjustment (seen by at least two cameras), "
      << s.solve.iterations << " iterations, " << fmt::format("{:.2f}", s.solve.solve_s) << " s ("
      << fmt::format("{:.1f}", s.detect_s) << " s finding the blobs).</p>\n";

    h << "<h2>Cameras</h2>\n<table><tr><th>camera</th><th>wand views</th><th>off the track</th><th>samples</th>"
         "<th>outliers</th><th>image error field px RMS</th><th>frame px RMS</th><th>world error mm</th><th>time offset µs</th><th>coverage</th>";
    const bool board = std::any_of(s.board.begin(), s.board.end(), [](const auto& b) { return b.has_value(); });
    if (board) h << "<th>board RMS px</th><th>board views</th>";
    h << "</tr>\n";
    for (size_t c = 0; c < nc; ++c) {
        const WandCameraStats& st = s.solve.stats.at(c);
        h << fmt::format("<tr><td>cam{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{:.4f}</td><td>{:.4f}</td>"
                         "<td>{:.5f}</td><td>{:.1f}</td><td>{:.0f} %</td>",
                         c, st.views, st.jumps, st.samples, st.outliers, st.image_error_px_rms,
                         st.image_error_frame_px_rms, st.world_error_mm,
                         s.cameras[c].field_time_offset_us, 100.0 * st.coverage);
        if (board) {
            if (c < s.board.size() && s.board[c]) h << fmt::format("<td>{:.4f}</td><td>{}</td>", s.board[c]->rms_px, s.board[c]->views_used);
            else h << "<td>–</td><td>–</td>";
        }
        h << "</tr>\n";
    }
    h << "</table>\n<p>Image error: RMS length of the 2D residual (observed − projected marker centre) in field "
         "pixels (720 × 288: x a frame column, y a field row, the pixels each field delivers; in frame pixels, as "
         "rig.yaml's K, a field row is two). World error: RMS distance of each fitted wand marker from the camera's ray "
         "through its image, i.e. the image error back-projected at the marker's depth. Time offset: the field start "
         "of each camera's field 0 on camera 0's clock, solved with the rest (cameras are not synchronised).</p>\n";

    h << "<h2>Why views were left out</h2>\n<table><tr><th>camera</th>";
    for (int r = 1; r < static_cast<int>(WandReject::kCount); ++r) h << "<th>" << to_string(static_cast<WandReject>(r)) << "</th>";
    h << "</tr>\n";
    for (size_t c = 0; c < nc; ++c) {
        h << "<tr><td>cam" << c << "</td>";
        for (int r = 1; r < static_cast<int>(WandReject::kCount); ++r) h << "<td>" << s.views.rejects.at(c)[static_cast<size_t>(r)] << "</td>";
        h << "</tr>\n";
    }
    h << "</table>\n";

    const auto& wl = s.solve.wand_length_error_mm;
    h << "<h2>Wand length</h2>\n";
    if (wl.empty()) h << "<p>Not measured: no sample had both end markers in two cameras.</p>\n";
    else
        h << fmt::format("<p>End markers triangulated on their own (the solved cameras, no wand model) in {} samples: "
                         "length error mean {:.2f} µm, RMS {:.2f} µm.</p><img src='wand_length.png' alt='wand length'>\n",
                         wl.size(), mean(wl) * 1e3, rms(wl) * 1e3);

    h << fmt::format("<h2>Rig frame</h2>\n<p>{} eye markers (ids {}) triangulated from their images at rest and fitted "
                     "to scenes/bodies.json (eye frame at rest = rig frame), then refined on {} images ({} left out: "
                     "partly behind the eye or off the fit): {:.1f} µm RMS in 3D, {:.4f} px RMS reprojection.</p>\n",
                     s.rig_frame.markers, fmt::join(s.rig_frame.marker_ids, ", "), s.rig_frame.views,
                     s.rig_frame.views_dropped, s.rig_frame.residual_mm_rms * 1e3, s.rig_frame.residual_px_rms);

    if (!s.truth.empty()) {
        h << "<h2>Against the true rig</h2>\n<p>" << html_escape(s.truth_file)
          << " (read after the solve, for these figures only).</p>\n<table><tr><th>camera</th><th>centre error µm</th>"
             "<th>rotation error °</th><th>fx error %</th><th>fy error %</th><th>time offset error µs</th>"
             "<th>projection error px RMS / max</th></tr>\n";
        for (size_t c = 0; c < s.truth.size(); ++c) {
            const CameraTruthError& e = s.truth[c];
            h << fmt::format("<tr><td>cam{}</td><td>{:.1f}</td><td>{:.5f}</td><td>{:.4f}</td><td>{:.4f}</td><td>{:.1f}</td>"
                             "<td>{:.4f} / {:.4f}</td></tr>\n",
                             c, e.centre_error_um, e.rotation_error_deg, e.fx_error_pct, e.fy_error_pct,
                             e.time_offset_error_us, e.projection_error_px_rms, e.projection_error_px_max);
        }
        h << "</table>\n<p>Projection error: points of the working volume projected by the calibrated and by the true "
             "camera (2 mm grid round the eye, inside the image).</p>\n";
    }

    h << "<h2>Residuals and coverage</h2>\n";
    for (size_t c = 0; c < nc; ++c) {
        h << fmt::format("<h3>cam{}</h3><p><img src='residuals_cam{}.png' alt='residuals'> <img src='coverage_cam{}.png' "
                         "alt='coverage'></p>\n",
                         c, c, c);
        if (c < s.board.size() && s.board[c] && !s.board[c]->coverage_png.empty())
            h << "<p>Board views: <img src='" << html_escape(s.board[c]->coverage_png) << "' alt='board coverage'></p>\n";
    }
    h << "<h2>Solve</h2>\n<ul>\n";
    for (const auto& n : s.solve.notes) h << "<li>" << html_escape(n) << "</li>\n";
    h << "</ul>\n";
    for (const auto& w : s.warnings) h << "<p>warning: " << html_escape(w) << "</p>\n";
    h << "</body></html>\n";
    if (!h) throw CalibrationError(fmt::format("{}/index.html: write failed", dir));
    return dir + "/index.html";
}

}  // namespace eyesim::calibration
