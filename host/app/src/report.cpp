#include "eyesim/app/report.hpp"

#include "eyesim/app/command.hpp"
#include "eyesim/render/scene_renderer.hpp"

#include <fmt/format.h>
#include <fmt/ranges.h>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>

#include <algorithm>
#include <filesystem>
#include <fstream>

namespace eyesim::app {

namespace {

/// The paper's Table 4 (ms), per stage; tracking ran on the FPGA and a separate PC path there.
struct PaperRow {
    Stage stage;
    const char* label;
    double paper_ms;  // < 0: not in the paper
};
constexpr PaperRow kTable4[] = {
    {Stage::kTracking, "Tracking (host)", -1.0},  {Stage::kCollision, "Collision detection", 2.3},
    {Stage::kTissue, "Tissue simulation", 1.5},   {Stage::kTransfer, "Geometry transfer", 1.7},
    {Stage::kMisc, "Misc", 1.0},                  {Stage::kRender, "Graphics rendering", 15.0},
};

StageSummary compute_summary(const StageTimer& t) {
    return t.summary_of_sum({Stage::kTracking, Stage::kCollision, Stage::kTissue});
}


}  // namespace

nlohmann::json loss_json(const LossCounts& c) {
    return {{"sequence_gaps", c.sequence_gaps},
            {"frames_lost", c.frames_lost},
            {"frames_repeated", c.frames_repeated},
            {"frames_late", c.frames_late},
            {"fields_lost", c.fields_lost},
            {"fields_out_of_order", c.fields_out_of_order},
            {"time_jumps", c.time_jumps},
            {"resyncs", c.resyncs},
            {"skipped_bytes", c.skipped_bytes},
            {"parse_errors", c.parse_errors},
            {"queue_overflows", c.device_queue_overflows},
            {"device_blobs_dropped", c.device_blobs_dropped},
            {"link_drops", c.link_drops}};
}

nlohmann::json latency_json(const RunStats& s) {
    auto pct = [](const frame::Samples& x) -> nlohmann::json {
        if (x.empty()) return nullptr;
        return {{"p50", percentile(x.v, 50)}, {"p99", percentile(x.v, 99)}, {"max", x.max}, {"frames", x.count}};
    };
    nlohmann::json j;
    j["latency_us"] = pct(s.latency_us);
    j["transfer_us"] = pct(s.transfer_us);
    j["ready_after_receive_us"] = pct(s.ready_us);
    // Always an object with p50 / p99 (null when never measured: no clock offset, or a replay without one).
    j["exposure_to_pose_us"] = s.exposure_to_pose_us.empty()
                                   ? nlohmann::json{{"p50", nullptr}, {"p99", nullptr}, {"max", nullptr}, {"frames", 0}}
                                   : pct(s.exposure_to_pose_us);
    j["latency_clocks"] = "latency_us: device field end (placed on the host clock through the ping offset) -> poses "
                          "ready (host clock); transfer_us: field end -> last packet received; ready_after_receive_us: "
                          "last packet received -> poses ready (host clock); exposure_to_pose_us: exposure mid of the "
                          "frame's reference field (device clock placed on the host clock) -> poses ready";
    if (!s.latency_note.empty()) j["latency_note"] = s.latency_note;
    if (s.device_clock_rate != 0.0) j["device_clock_rate"] = s.device_clock_rate;
    return j;
}

std::string latency_line(const RunStats& s) {
    std::string line;
    if (!s.latency_us.empty())
        line = fmt::format("Latency field end → poses ready: p50 {:.0f} µs, p99 {:.0f} µs (field end → received p50 {:.0f} "
                           "µs; received → poses ready p50 {:.0f} µs)",
                           percentile(s.latency_us.v, 50), percentile(s.latency_us.v, 99), percentile(s.transfer_us.v, 50),
                           percentile(s.ready_us.v, 50));
    else if (!s.ready_us.empty())
        line = fmt::format("Latency received → poses ready: p50 {:.0f} µs, p99 {:.0f} µs; field end → poses ready not "
                           "measured: {}",
                           percentile(s.ready_us.v, 50), percentile(s.ready_us.v, 99), s.latency_note);
    return line;
}

nlohmann::json precision_json(const RunStats& s) {
    if (!s.precision) return nullptr;
    const frame::PrecisionStats& p = s.patches;
    nlohmann::json why = nlohmann::json::object();
    for (int r = 1; r < tracking::kFitRefusalCount; ++r)
        why[tracking::to_string(static_cast<tracking::FitRefusal>(r))] = p.refused[static_cast<size_t>(r)];
    const uint64_t tried = p.refined + p.refused_total() + p.missing_patch;
    return {{"patches", p.patches},
            {"refined", p.refined},
            {"refused", why},
            {"refused_total", p.refused_total()},
            {"missing_patch", p.missing_patch},
            {"hinted_fits", p.hinted_fits},
            {"unmatched_patches", p.unmatched},
            {"incomplete_patches", p.incomplete},
            {"refined_fraction", tried ? nlohmann::json(double(p.refined) / double(tried)) : nlohmann::json(nullptr)}};
}

std::string precision_line(const RunStats& s) {
    if (!s.precision) return "";
    const frame::PrecisionStats& p = s.patches;
    std::string why;
    for (int r = 1; r < tracking::kFitRefusalCount; ++r)
        if (p.refused[static_cast<size_t>(r)] > 0)
            why += fmt::format("{}{} {}", why.empty() ? "" : ", ", tracking::to_string(static_cast<tracking::FitRefusal>(r)),
                               p.refused[static_cast<size_t>(r)]);
    return fmt::format("Precision: {} patches; {} markers refined, {} refused ({}), {} missing a patch; {} fits "
                       "with the instrument's shaft left out; {} patches unmatched, {} incomplete",
                       p.patches, p.refined, p.refused_total(), why.empty() ? "none" : why, p.missing_patch,
                       p.hinted_fits, p.unmatched, p.incomplete);
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

namespace {

/// Minimal line plot (OpenCV), for the report. Text must be ASCII (OpenCV's Hershey fonts have no µ or →).
/// putText with the micro sign: Hershey fonts have no "µ", so it is drawn as a "u" with a descender.
void put_text(cv::Mat& img, const std::string& text, cv::Point at, double scale, const cv::Scalar& ink) {
    const std::string micro = "\u00b5";
    size_t pos = 0;
    int base = 0;
    while (pos <= text.size()) {
        const size_t next = text.find(micro, pos);
        const std::string part = text.substr(pos, next == std::string::npos ? std::string::npos : next - pos);
        cv::putText(img, part, at, cv::FONT_HERSHEY_SIMPLEX, scale, ink, 1, cv::LINE_AA);
        at.x += cv::getTextSize(part, cv::FONT_HERSHEY_SIMPLEX, scale, 1, &base).width;
        if (next == std::string::npos) break;
        const cv::Size u = cv::getTextSize("u", cv::FONT_HERSHEY_SIMPLEX, scale, 1, &base);
        cv::putText(img, "u", at, cv::FONT_HERSHEY_SIMPLEX, scale, ink, 1, cv::LINE_AA);
        const int x = at.x + std::max(1, u.width / 6);
        cv::line(img, {x, at.y - u.height / 2}, {x, at.y + u.height / 2}, ink, 1, cv::LINE_AA);
        at.x += u.width;
        pos = next + micro.size();
    }
}

/// A "nice" tick step (1, 2 or 5 × 10^k) giving about `ticks` intervals over `range`.
double nice_step(double range, int ticks) {
    const double raw = range / std::max(1, ticks);
    const double mag = std::pow(10.0, std::floor(std::log10(raw)));
    for (const double f : {1.0, 2.0, 5.0, 10.0})
        if (f * mag >= raw) return f * mag;
    return 10.0 * mag;
}

/// Tick label with as many decimals as the step needs.
std::string tick_label(double v, double step) {
    const int decimals = std::max(0, int(std::ceil(-std::log10(step) - 1e-9)));
    return fmt::format("{:.{}f}", v, decimals);
}

/// Line plot of per-frame series against time (frames spread evenly over `duration_s`). The y axis ends at the
/// 99th percentile of all values (with margin) so that one spike cannot flatten the rest; values above it are
/// drawn at the top edge and counted in the plot.
void plot_lines(const std::string& path, const std::string& title, const std::string& ylabel, double duration_s,
                const std::vector<std::pair<std::string, std::vector<double>>>& series) {
    const int W = 900, H = 360, L = 70, R = 170, T = 40, B = 50;
    cv::Mat img(H, W, CV_8UC3, cv::Scalar(255, 255, 255));
    std::vector<double> all;
    size_t n = 0;
    for (const auto& [name, v] : series) {
        n = std::max(n, v.size());
        for (double y : v)
            if (std::isfinite(y)) all.push_back(y);
    }
    double ymax = all.empty() ? 1.0 : percentile(all, 99) * 1.25;
    if (!(ymax > 0)) ymax = 1.0;
    const double ystep = nice_step(ymax, 4);
    ymax = std::ceil(ymax / ystep - 1e-9) * ystep;
    size_t clipped = 0;
    for (double y : all) clipped += y > ymax;
    const cv::Scalar ink(30, 30, 30), grid(220, 220, 220);
    for (double v = 0; v <= ymax + 1e-9 * ymax; v += ystep) {
        const int y = H - B - int(double(H - T - B) * v / ymax);
        cv::line(img, {L, y}, {W - R, y}, grid, 1);
        put_text(img, tick_label(v, ystep), {5, y + 4}, 0.4, ink);
    }
    const double xmax = duration_s > 0 ? duration_s : double(std::max<size_t>(n, 2) - 1) * 0.02;
    const double xstep = nice_step(xmax, 8);
    for (double v = 0; v <= xmax + 1e-9; v += xstep) {
        const int x = L + int(double(W - L - R) * v / xmax);
        cv::line(img, {x, H - B}, {x, H - B + 4}, ink, 1);
        put_text(img, tick_label(v, xstep), {x - 8, H - B + 18}, 0.4, ink);
    }
    cv::rectangle(img, {L, T}, {W - R, H - B}, ink, 1);
    put_text(img, title, {L, 25}, 0.55, ink);
    put_text(img, ylabel, {5, T - 16}, 0.4, ink);
    put_text(img, "time [s]", {W - R - 60, H - 8}, 0.45, ink);
    if (clipped)
        put_text(img, fmt::format("{} values above {} {} drawn at the top", clipped, tick_label(ymax, ystep), ylabel),
                 {L + 5, T + 14}, 0.38, ink);
    static const cv::Scalar colours[] = {{180, 90, 20}, {30, 120, 230}, {40, 160, 40}, {160, 40, 160}, {20, 20, 200}, {120, 120, 0}};
    int si = 0;
    for (const auto& [name, v] : series) {
        const cv::Scalar c = colours[si % 6];
        std::vector<cv::Point> pts;
        for (size_t i = 0; i < v.size(); ++i)
            pts.emplace_back(L + int(double(W - L - R) * double(i) / double(std::max<size_t>(n - 1, 1))),
                             H - B - int(double(H - T - B) * std::clamp(v[i], 0.0, ymax) / ymax));
        if (pts.size() > 1) cv::polylines(img, pts, false, c, 1, cv::LINE_AA);
        cv::line(img, {W - R + 10, T + 12 + 18 * si}, {W - R + 30, T + 12 + 18 * si}, c, 2);
        put_text(img, name, {W - R + 35, T + 16 + 18 * si}, 0.42, ink);
        ++si;
    }
    cv::imwrite(path, img);
}

}  // namespace

// ---------------------------------------------------------------------------------------------------------------
// Snapshots

Snapshotter::Snapshotter(int width, int height) {
    render::RenderConfig cfg;
    renderer_ = render::SceneRenderer::create(width, height, cfg, error_);
}

Snapshotter::~Snapshotter() = default;

std::string Snapshotter::renderer_name() const { return renderer_ ? renderer_->renderer_name() : std::string(); }

SceneCopy copy_scene(const Simulator& sim) {
    SceneCopy c;
    c.frame = sim.timer().frames() ? sim.timer().frames() - 1 : 0;
    c.time_s = sim.scores().task_time_s;
    const auto& mesh = sim.tissue_mesh();
    c.tissue_vertices_eye_mm = mesh.vertices_mm;
    c.tissue_triangles = mesh.triangles;
    c.tissue_is_retina = sim.scene().tissue.kind == sim::scenes::TissueKind::kRetina;
    for (const sim::collision::PosedInstrument* p : {sim.tissue_instrument(), sim.light_instrument()}) {
        if (!p) continue;
        SceneCopy::Inst in;
        for (const auto& v : p->vertices_local_mm()) in.vertices_eye_mm.push_back(p->instrument_to_eye() * v);
        in.triangles = &p->instrument().mesh.triangles;
        in.tip_eye_mm = p->tip_eye_mm();
        in.forward_eye = p->forward_eye();
        in.light = p->instrument().kind == sim::collision::InstrumentKind::LightPipe;
        c.instruments.push_back(std::move(in));
    }
    for (uint32_t n : sim.grabbed_nodes())
        if (n < mesh.vertices_mm.size()) c.highlight_eye_mm.push_back(mesh.vertices_mm[n]);
    return c;
}

bool Snapshotter::snap(const SceneCopy& c, const std::string& path) {
    render::StereoImages img;
    return render(c, img) && render::write_side_by_side_png(path, img, error_);
}

bool write_animation(const std::string& path, const std::vector<SceneCopy>& frames, double fps, Snapshotter& renderer,
                     std::string& error) {
    if (frames.empty() || !(fps > 0)) {
        error = path + ": no frames to animate";
        return false;
    }
    render::StereoImages img;
    cv::VideoWriter video;
    cv::Mat bgr;
    for (const SceneCopy& c : frames) {
        if (!renderer.render(c, img)) {
            error = renderer.error();
            return false;
        }
        if (!video.isOpened()) {
            const cv::Size size(2 * img.width, img.height);
            for (const int fourcc : {cv::VideoWriter::fourcc('a', 'v', 'c', '1'), cv::VideoWriter::fourcc('m', 'p', '4', 'v')})
                if (video.open(path, cv::CAP_FFMPEG, fourcc, fps, size)) break;
            if (!video.isOpened()) {
                error = path + ": cannot write video (OpenCV has no FFmpeg H.264 or MPEG-4 encoder)";
                return false;
            }
            bgr.create(size, CV_8UC3);
        }
        for (int v = 0; v < 2; ++v) {
            const cv::Mat rgba(img.height, img.width, CV_8UC4, (v == 0 ? img.left_rgba : img.right_rgba).data());
            cv::Mat half = bgr(cv::Rect(v * img.width, 0, img.width, img.height));
            cv::cvtColor(rgba, half, cv::COLOR_RGBA2BGR);
        }
        video.write(bgr);
    }
    video.release();
    return true;
}

void Snapshotter::set_objects(const std::vector<sim::collision::ConvexObject>& objects) {
    objects_.clear();
    for (const auto& o : objects) objects_.push_back(sim::collision::convex_object_mesh(o));
}

bool Snapshotter::render(const SceneCopy& c, render::StereoImages& img) {
    if (!renderer_) return false;
    std::vector<render::InstrumentView> views;
    for (const auto& m : objects_) {
        render::InstrumentView ov;
        ov.mesh.vertices_eye_mm = m.vertices_mm;
        ov.mesh.triangles = m.triangles;
        ov.tip_eye_mm = m.vertices_mm.front();
        ov.forward_eye = Eigen::Vector3f::UnitZ();
        views.push_back(ov);
    }
    for (const auto& in : c.instruments) {
        render::InstrumentView iv;
        iv.mesh.vertices_eye_mm = in.vertices_eye_mm;
        iv.mesh.triangles = *in.triangles;
        iv.tip_eye_mm = in.tip_eye_mm;
        iv.forward_eye = in.forward_eye;
        iv.is_light_pipe = in.light;
        views.push_back(iv);
    }
    render::SceneFrame f;
    f.tissue.vertices_eye_mm = c.tissue_vertices_eye_mm;
    f.tissue.triangles = c.tissue_triangles;
    f.tissue_is_retina = c.tissue_is_retina;
    f.instruments = views;
    f.highlight_nodes_eye_mm = c.highlight_eye_mm;
    renderer_->render(f, img);
    return true;
}

// ---------------------------------------------------------------------------------------------------------------
// Text and JSON

void print_report(std::FILE* out, const RunReport& r) {
    const Simulator& sim = *r.sim;
    const StageTimer& t = sim.timer();
    std::fprintf(out, "%s\n", r.title.c_str());
    std::fprintf(out, "source: %s; %zu frames; scene '%s'\n\n", r.source.c_str(), t.frames(), sim.scene().name.c_str());
    std::fprintf(out, "Table 4: time per frame (this machine, host stages measured per frame; paper: Athlon 1.4 GHz)\n");
    std::fprintf(out, "  %-22s %10s %10s %10s %12s\n", "stage", "p50 [ms]", "p99 [ms]", "max [ms]", "paper [ms]");
    for (const auto& row : kTable4) {
        const StageSummary s = row.stage == Stage::kRender ? t.summary_where_ran(row.stage) : t.summary(row.stage);
        const std::string paper = row.paper_ms < 0 ? std::string("-") : fmt::format("{:.1f}", row.paper_ms);
        std::fprintf(out, "  %-22s %10.4f %10.4f %10.4f %12s\n", row.label, s.p50_us / 1e3, s.p99_us / 1e3,
                     s.max_us / 1e3, paper.c_str());
    }
    const StageSummary compute = compute_summary(t);
    std::fprintf(out, "  %-22s %10.4f %10.4f %10.4f %12s\n", "host compute (T+C+S)", compute.p50_us / 1e3,
                 compute.p99_us / 1e3, compute.max_us / 1e3, "3.8");
    const StageSummary sim_all = t.summary_of_sum({Stage::kTracking, Stage::kCollision, Stage::kTissue, Stage::kTransfer,
                                                   Stage::kMisc});
    std::fprintf(out, "  %-22s %10.4f %10.4f %10.4f %12s\n", "all but rendering", sim_all.p50_us / 1e3,
                 sim_all.p99_us / 1e3, sim_all.max_us / 1e3, "7.0");
    size_t rendered = 0;
    for (size_t i = 0; i < t.frames(); ++i) rendered += t.row(i)[size_t(Stage::kRender)] > 0.0;
    std::fprintf(out, "  (rendering: %zu snapshot frames, stereo with shadow maps, off-screen; the paper renders every "
                      "frame)\n", rendered);
    if (r.accuracy.available)
        std::fprintf(out, "\nTracking accuracy against truth (%zu frames): 3D markers %.1f µm RMS (p95 %.1f), tip %.1f µm RMS "
                          "(p95 %.1f), eye rotation %.4f° RMS\n",
                     r.accuracy.frames, r.accuracy.marker3d_rms_um, r.accuracy.marker3d_p95_um, r.accuracy.tip_rms_um,
                     r.accuracy.tip_p95_um, r.accuracy.eye_rot_rms_deg);
    if (r.stats) {
        if (const std::string l = latency_line(*r.stats); !l.empty()) std::fprintf(out, "%s\n", l.c_str());
        if (const std::string l = precision_line(*r.stats); !l.empty()) std::fprintf(out, "%s\n", l.c_str());
        const std::string lost = loss_summary(r.stats->loss);
        std::fprintf(out, "Link: %s%s%s\n", lost.empty() ? "nothing lost" : lost.c_str(),
                     r.link_end.empty() ? "" : "; ended: ", r.link_end.c_str());
    }
    const Scores& s = sim.scores();
    std::fprintf(out, "\nScores: task %.2f s, path %.1f mm, grabs %llu, ", s.task_time_s, s.path_length_mm,
                 (unsigned long long)s.grabs);
    if (s.membrane_area_mm2 > 0)
        std::fprintf(out, "peeled %.2f mm² (%.1f %% of %.1f mm²), ", s.peeled_area_mm2, peeled_percent(s),
                     s.membrane_area_mm2);
    std::fprintf(out, "springs torn %llu, removed %.3f mm², detached %llu nodes, retina contacts %llu, object contacts "
                      "%llu, lift-off warnings %llu, tear warnings %llu, tissue contact %llu frames\n",
                 (unsigned long long)s.springs_torn, s.removed_area_mm2, (unsigned long long)s.nodes_detached,
                 (unsigned long long)s.eye_contacts, (unsigned long long)s.object_contacts,
                 (unsigned long long)s.lift_off_warnings, (unsigned long long)s.tear_warnings,
                 (unsigned long long)s.tissue_contact_frames);
    const Verdict v = judge(sim.scene().scoring, s);
    if (v.checked && v.passed) std::fprintf(out, "Task passed: every rule of the scene held\n");
    if (v.checked && !v.passed) std::fprintf(out, "Task failed: %s\n", fmt::format("{}", fmt::join(v.failed, "; ")).c_str());
    // Events: the first of each burst (events of one kind within 0.1 s are one line).
    std::fprintf(out, "Events (%zu):\n", sim.events().size());
    double last_t[16];
    std::fill(std::begin(last_t), std::end(last_t), -1e9);
    int shown = 0;
    for (const Event& e : sim.events()) {
        double& lt = last_t[int(e.kind)];
        const bool burst = e.time_s - lt < 0.1;
        lt = e.time_s;
        if (burst) continue;
        if (++shown > 25) {
            std::fprintf(out, "  …\n");
            break;
        }
        std::fprintf(out, "  %7.2f s  %-16s %g\n", e.time_s, to_string(e.kind), double(e.value));
    }
}

nlohmann::json report_json(const RunReport& r) {
    const Simulator& sim = *r.sim;
    const StageTimer& t = sim.timer();
    nlohmann::json j;
    j["scene"] = sim.scene().name;
    j["source"] = r.source;
    j["frames"] = t.frames();
    nlohmann::json stages;
    for (const auto& row : kTable4) {
        const StageSummary s = row.stage == Stage::kRender ? t.summary_where_ran(row.stage) : t.summary(row.stage);
        stages[to_string(row.stage)] = {{"p50_us", s.p50_us}, {"p99_us", s.p99_us}, {"max_us", s.max_us},
                                        {"paper_us", row.paper_ms < 0 ? nlohmann::json(nullptr) : nlohmann::json(row.paper_ms * 1e3)}};
    }
    j["stages"] = stages;
    const StageSummary c = compute_summary(t);
    j["host_compute_us"] = {{"p50", c.p50_us}, {"p99", c.p99_us}, {"max", c.max_us}};
    if (r.accuracy.available) {
        j["marker3d_rms_um"] = r.accuracy.marker3d_rms_um;
        j["tip_rms_um"] = r.accuracy.tip_rms_um;
        j["eye_rot_rms_deg"] = r.accuracy.eye_rot_rms_deg;
    }
    if (r.stats) {
        j.update(latency_json(*r.stats));
        j["precision"] = precision_json(*r.stats);
        j["errors"] = r.stats->parse_errors;
        j["loss"] = loss_json(r.stats->loss);
    }
    const Scores& s = sim.scores();
    j["scores"] = {{"task_time_s", s.task_time_s}, {"path_length_mm", s.path_length_mm},
                   {"tissue_contact_frames", s.tissue_contact_frames}, {"grabs", s.grabs},
                   {"springs_torn", s.springs_torn}, {"torn_area_mm2", s.torn_area_mm2},
                   {"removed_area_mm2", s.removed_area_mm2}, {"nodes_detached", s.nodes_detached},
                   {"eye_contacts", s.eye_contacts}, {"object_contacts", s.object_contacts},
                   {"lift_off_warnings", s.lift_off_warnings}, {"tear_warnings", s.tear_warnings},
                   {"not_pi_convex_frames", s.not_pi_convex_frames}, {"events_dropped", s.events_dropped},
                   {"retina_contacts", s.eye_contacts}, {"membrane_area_mm2", s.membrane_area_mm2},
                   {"peeled_area_mm2", s.peeled_area_mm2}, {"peeled_percent", peeled_percent(s)}};
    const Verdict v = judge(sim.scene().scoring, s);
    if (v.checked) j["passed"] = v.passed, j["failed_rules"] = v.failed;
    nlohmann::json ev = nlohmann::json::array();
    for (const Event& e : sim.events()) ev.push_back({{"t_s", e.time_s}, {"kind", to_string(e.kind)}, {"value", e.value}});
    j["events"] = ev;
    j["warnings"] = r.warnings;
    if (!r.link_end.empty()) j["link_end"] = r.link_end;
    j["snapshots"] = nlohmann::json::array();
    for (const auto& sn : r.snapshots) j["snapshots"].push_back({{"t_s", sn.time_s}, {"file", sn.file}});
    if (!r.animation.empty()) j["animation"] = {{"file", r.animation}, {"frames", r.animation_frames}};
    return j;
}

// ---------------------------------------------------------------------------------------------------------------
// Report folder

std::string write_report(const std::string& dir, const RunReport& r) {
    std::error_code ec;
    std::filesystem::create_directories(dir, ec);
    if (ec) throw Error(dir + ": cannot create report folder: " + ec.message());
    const Simulator& sim = *r.sim;
    const StageTimer& t = sim.timer();

    // Plots.
    std::vector<std::pair<std::string, std::vector<double>>> stages;
    for (const auto& row : kTable4) {
        std::vector<double> v;
        for (size_t i = 0; i < t.frames(); ++i) v.push_back(t.row(i)[size_t(row.stage)]);
        stages.push_back({to_string(row.stage), std::move(v)});
    }
    stages.pop_back();  // render time is sparse (snapshot frames only): its own table row, not this plot
    plot_lines(dir + "/stages.png", "Host stage times per frame", "\u00b5s", sim.scores().task_time_s, stages);
    if (r.stats && !r.stats->latency_us.empty())
        plot_lines(dir + "/latency.png", "Latency per frame: field end -> packet received -> poses ready", "\u00b5s",
                   sim.scores().task_time_s,
                   {{"received", r.stats->transfer_us.v}, {"poses ready", r.stats->latency_us.v}});

    std::ofstream h(dir + "/index.html");
    if (!h) throw Error(dir + "/index.html: cannot write");
    h << "<!doctype html><html><head><meta charset='utf-8'><title>" << html_escape(r.title) << "</title>"
      << "<style>body{font-family:sans-serif;max-width:1100px;margin:2em auto;color:#222}"
         "table{border-collapse:collapse}td,th{border:1px solid #ccc;padding:4px 10px;text-align:right}"
         "th{background:#f0f0f0}td:first-child{text-align:left}img{max-width:100%}</style></head><body>\n";
    h << "<h1>" << html_escape(r.title) << "</h1>\n<p>Scene <b>" << html_escape(sim.scene().name) << "</b>: "
      << html_escape(sim.scene().description) << ".<br>Source: " << html_escape(r.source) << "; " << t.frames()
      << " frames.</p>\n";
    h << "<h2>Frame budget (paper Table 4)</h2>\n<table><tr><th>stage</th><th>p50 ms</th><th>p99 ms</th><th>max ms</th>"
         "<th>paper ms</th></tr>\n";
    for (const auto& row : kTable4) {
        const StageSummary s = row.stage == Stage::kRender ? t.summary_where_ran(row.stage) : t.summary(row.stage);
        h << fmt::format("<tr><td>{}</td><td>{:.4f}</td><td>{:.4f}</td><td>{:.4f}</td><td>{}</td></tr>\n", row.label,
                         s.p50_us / 1e3, s.p99_us / 1e3, s.max_us / 1e3,
                         row.paper_ms < 0 ? std::string("–") : fmt::format("{:.1f}", row.paper_ms));
    }
    const StageSummary c = compute_summary(t);
    h << fmt::format("<tr><td><b>host compute</b> (tracking + collision + tissue)</td><td>{:.4f}</td><td>{:.4f}</td>"
                     "<td>{:.4f}</td><td>3.8</td></tr></table>\n",
                     c.p50_us / 1e3, c.p99_us / 1e3, c.max_us / 1e3);
    h << "<p>Rendering time counts only frames with a snapshot"
      << (r.renderer.empty() ? "" : " (renderer: " + html_escape(r.renderer) + ")") << ".</p>\n";
    h << "<img src='stages.png' alt='stage times'>\n";
    if (r.accuracy.available)
        h << fmt::format("<h2>Tracking accuracy against truth</h2><p>{} frames: 3D markers {:.1f} µm RMS (p95 {:.1f} µm); "
                         "instrument tip {:.1f} µm RMS (p95 {:.1f} µm); eye rotation {:.4f}° RMS.</p>\n",
                         r.accuracy.frames, r.accuracy.marker3d_rms_um, r.accuracy.marker3d_p95_um, r.accuracy.tip_rms_um,
                         r.accuracy.tip_p95_um, r.accuracy.eye_rot_rms_deg);
    if (r.stats && !r.stats->latency_us.empty())
        h << fmt::format("<h2>Latency</h2><p>Field end → poses ready: p50 {:.0f} µs, p99 {:.0f} µs. Parse errors: {}.</p>"
                         "<img src='latency.png' alt='latency'>\n",
                         percentile(r.stats->latency_us.v, 50), percentile(r.stats->latency_us.v, 99), r.stats->parse_errors);
    if (!r.animation.empty())
        h << fmt::format("<h2>The whole run</h2><p>Stereo microscope view, {} frames (left and right eyepiece side by "
                         "side).</p><video src='{}' controls loop muted autoplay style='max-width:100%'></video>\n",
                         r.animation_frames, r.animation);
    if (!r.snapshots.empty()) {
        h << "<h2>Stereo microscope views</h2>\n";
        for (const auto& sn : r.snapshots)
            h << fmt::format("<p>t = {:.2f} s<br><img src='{}' alt='stereo snapshot'></p>\n", sn.time_s, sn.file);
    }
    const Scores& s = sim.scores();
    h << "<h2>Scores</h2><table>";
    auto row = [&h](const char* k, const std::string& v) { h << "<tr><td>" << k << "</td><td>" << v << "</td></tr>"; };
    row("task time", fmt::format("{:.2f} s", s.task_time_s));
    row("instrument path length", fmt::format("{:.1f} mm", s.path_length_mm));
    row("frames in tissue contact", std::to_string(s.tissue_contact_frames));
    row("grabs", std::to_string(s.grabs));
    if (s.membrane_area_mm2 > 0)
        row("membrane peeled", fmt::format("{:.2f} mm² ({:.1f} % of {:.1f} mm²)", s.peeled_area_mm2, peeled_percent(s),
                                           s.membrane_area_mm2));
    row("springs torn", std::to_string(s.springs_torn));
    row("tissue removed", fmt::format("{:.3f} mm²", s.removed_area_mm2));
    row("retina nodes detached", std::to_string(s.nodes_detached));
    row("retina contacts (case 2)", std::to_string(s.eye_contacts));
    row("object contacts (case 3)", std::to_string(s.object_contacts));
    row("retina lift-off warnings", std::to_string(s.lift_off_warnings));
    row("tear warnings", std::to_string(s.tear_warnings));
    h << "</table>\n";
    const Verdict v = judge(sim.scene().scoring, s);
    if (v.checked)
        h << "<p><b>Task " << (v.passed ? "passed" : "failed") << "</b>"
          << (v.passed ? ": every rule of the scene held." : ": " + html_escape(fmt::format("{}", fmt::join(v.failed, "; "))))
          << "</p>\n";
    h << "<h2>Events</h2><table><tr><th>t [s]</th><th>event</th><th>value</th></tr>\n";
    size_t shown = 0;
    for (const Event& e : sim.events()) {
        if (++shown > 200) break;
        h << fmt::format("<tr><td>{:.2f}</td><td>{}</td><td>{:g}</td></tr>\n", e.time_s, to_string(e.kind), double(e.value));
    }
    h << "</table>\n";
    for (const auto& w : r.warnings) h << "<p>warning: " << html_escape(w) << "</p>\n";
    h << "</body></html>\n";
    return dir + "/index.html";
}

}  // namespace eyesim::app
