#include "eyesim/rig/scenario.hpp"

#include "eyesim/rig/error.hpp"
#include "eyesim/rig/surgeon.hpp"

#include <fmt/format.h>
#include <fmt/ranges.h>

#include <algorithm>
#include <cmath>

namespace eyesim::rig {

namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr double kDeg = kPi / 180.0;

/// splitmix64: a tiny, portable, well-mixed generator (std distributions differ between libraries).
struct Rng {
    uint64_t s;
    uint64_t next() {
        uint64_t z = (s += 0x9E3779B97F4A7C15ull);
        z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
        z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
        return z ^ (z >> 31);
    }
    double uniform(double lo, double hi) { return lo + (hi - lo) * static_cast<double>(next() >> 11) * 0x1.0p-53; }
};

uint64_t hash_name(const std::string& s) {
    uint64_t h = 1469598103934665603ull;
    for (char c : s) h = (h ^ static_cast<uint8_t>(c)) * 1099511628211ull;
    return h;
}

double smoothstep(double a, double b, double x) {
    if (x <= a) return 0.0;
    if (x >= b) return 1.0;
    const double u = (x - a) / (b - a);
    return u * u * u * (u * (u * 6 - 15) + 10);
}

}  // namespace

std::vector<std::string> scenario_names() {
    return {"static", "sweep", "surgery", "fast", "occlusion", "injection", "peel", "peel-hard", "vitrectomy",
            "checkerboard", "wand"};
}

namespace {

/// Point at geodesic polar coordinates (rho, theta) about `c` on the sphere of radius `r` (any tangent basis).
Eigen::Vector3d on_sphere(double r, const Eigen::Vector3d& c, double rho, double theta) {
    const Eigen::Vector3d a = std::fabs(c.x()) < 0.9 ? Eigen::Vector3d::UnitX() : Eigen::Vector3d::UnitY();
    const Eigen::Vector3d e1 = (a - a.dot(c) * c).normalized(), e2 = e1.cross(c);  // as the host's mesh
    const double ang = rho / r;
    const Eigen::Vector3d dir = std::cos(theta) * e1 + std::sin(theta) * e2;
    return r * (std::cos(ang) * c + std::sin(ang) * dir);
}

/// The epiretinal membrane's surface point at (rho, theta), with the tip `lift_mm` above it (towards the centre).
Eigen::Vector3d above_membrane(double rho, double theta, double lift_mm) {
    return on_sphere(surgeon::kMembraneSurface_mm - lift_mm, surgeon::kMembraneCentreDir, rho * (1.0 - lift_mm / surgeon::kMembraneSurface_mm), theta);
}

/// Shaft x axis of the host's instrument frame: eye +x (or +y) made perpendicular to the forward axis z.
Eigen::Vector3d shaft_x(const Eigen::Vector3d& z) {
    const Eigen::Vector3d a = std::fabs(z.x()) < 0.9 ? Eigen::Vector3d::UnitX() : Eigen::Vector3d::UnitY();
    return (a - a.dot(z) * z).normalized();
}

}  // namespace

double Scenario::eval(const std::vector<Wave>& waves, double t_s) {
    double v = 0;
    for (const Wave& w : waves) v += w.amp * std::sin(2 * kPi * w.freq_hz * t_s + w.phase);
    return v;
}

Scenario Scenario::make(const std::string& name, uint64_t seed, double duration_us, const Bodies& bodies,
                        const std::vector<CameraModel>& cameras) {
    const auto names = scenario_names();
    if (std::find(names.begin(), names.end(), name) == names.end())
        throw RigError(fmt::format(
            "scenario: name: unknown scenario '{}' ({})", name, fmt::join(names, ", ")));
    if (name == "checkerboard") {
        // The still scene, and a person holding the calibration board in front of each camera in turn.
        Scenario s = make("static", seed, duration_us, bodies);
        s.name_ = name;
        s.board_ = std::make_shared<const BoardMotion>(
            BoardMotion::plan(kCheckerboard, cameras.empty() ? default_rig() : cameras, seed, duration_us));
        return s;
    }
    Scenario s;
    s.name_ = name;
    s.bodies_ = bodies;
    Rng rng{seed ^ hash_name(name)};
    const double dur_s = std::max(duration_us, 0.0) * 1e-6;

    InstrumentKind tissue = InstrumentKind::kForceps;
    if (name == "sweep") tissue = InstrumentKind::kPick;
    if (name == "fast") tissue = InstrumentKind::kVitrector;
    if (name == "occlusion" || name == "injection") tissue = InstrumentKind::kInjection;
    const bool peel = name == "peel" || name == "peel-hard";
    if (peel) tissue = InstrumentKind::kForceps;
    if (name == "vitrectomy") tissue = InstrumentKind::kVitrector;
    s.injection_ = name == "injection";
    s.kinds_ = {tissue, InstrumentKind::kLightPipe};
    (void)bodies.instrument(tissue);
    (void)bodies.instrument(InstrumentKind::kLightPipe);

    // Motion amplitudes (tilt in rad, insertion in mm) and frequency bands per scenario.
    struct Band { double tilt_amp, tilt_f0, tilt_f1, ins_amp, ins_f0, ins_f1, eye_amp, eye_f0, eye_f1; };
    Band b{};
    if (name == "static") b = {0, 0, 0, 0, 0, 0, 0, 0, 0};
    if (name == "sweep") b = {22 * kDeg, 0.04, 0.12, 6.0, 0.05, 0.10, 8 * kDeg, 0.03, 0.08};
    if (name == "surgery" || peel || name == "vitrectomy") b = {1.5 * kDeg, 0.3, 0.8, 0.8, 0.2, 0.6, 2 * kDeg, 0.1, 0.4};
    if (name == "fast") b = {14 * kDeg, 2.0, 3.5, 4.0, 1.5, 3.0, 6 * kDeg, 0.8, 2.0};
    if (name == "occlusion") b = {16 * kDeg, 0.1, 0.3, 3.0, 0.1, 0.3, 14 * kDeg, 0.1, 0.3};
    if (name == "injection") b = {1.0 * kDeg, 0.1, 0.3, 0.0, 0.1, 0.3, 1 * kDeg, 0.1, 0.3};

    for (int k = 0; k < 2; ++k) {
        InstrumentMotion m;
        m.tilt_x0 = rng.uniform(-10, 10) * kDeg;
        m.tilt_y0 = rng.uniform(-10, 10) * kDeg;
        m.insertion0 = name == "surgery" && k == 0 ? rng.uniform(15, 17) : rng.uniform(8, 12);
        for (int w = 0; w < 2; ++w) {
            m.tilt_x.push_back({b.tilt_amp / 1.5, rng.uniform(b.tilt_f0, b.tilt_f1), rng.uniform(0, 2 * kPi)});
            m.tilt_y.push_back({b.tilt_amp / 1.5, rng.uniform(b.tilt_f0, b.tilt_f1), rng.uniform(0, 2 * kPi)});
            m.insertion.push_back({b.ins_amp / 1.5, rng.uniform(b.ins_f0, b.ins_f1), rng.uniform(0, 2 * kPi)});
        }
        if (name == "surgery" && k == 0) {
            // Peeling strokes: slow drag of the tip across the retina, repeated.
            m.tilt_x.push_back({5 * kDeg, 0.25, rng.uniform(0, 2 * kPi)});
        }
        if (name == "injection" && k == 0) {
            m.tilt_x0 = rng.uniform(-4, 4) * kDeg;
            m.tilt_y0 = rng.uniform(-4, 4) * kDeg;
            m.tilt_x.push_back({0.0, 1.0, 0.0});
            m.flick_s = 3.0;
        }
        if (name == "occlusion" && k == 0) {
            // The tissue instrument is pulled out of the eye (markers leave the view) and reinserted.
            m.retract_start_s = 0.3 * dur_s;
            m.retract_end_s = 0.7 * dur_s;
        }
        s.motion_.push_back(std::move(m));
    }
    if (name == "occlusion") {
        // Drive both instruments towards each other so the shafts cross in some views.
        s.motion_[0].tilt_x0 = 18 * kDeg;
        s.motion_[1].tilt_x0 = -18 * kDeg;
    }

    // Synthetic surgeons: waypoints on a nominal timeline, compressed into shorter runs.
    if (peel || name == "vitrectomy") {
        const bool hard = name == "peel-hard";
        const double nominal_s = peel ? 8.0 : 6.4;
        const double k = dur_s > 0 && dur_s < nominal_s ? dur_s / nominal_s : 1.0;
        auto jit = [&](double a) { return rng.uniform(-a, a); };
        auto add = [&](double t, const Eigen::Vector3d& p, double pedal) {
            s.path_.push_back({std::max(0.0, (t + jit(0.04)) * k), p, pedal});
        };
        if (peel) {
            // Grasp near the edge on the trocar's side of the membrane, lift and pull across it; release,
            // regrasp further round the edge, pull again; withdraw.
            const Eigen::Vector3d troc = bodies.eye.trocars.at(0).position_eye_mm;
            const double theta_troc = std::atan2(troc.y(), troc.x());
            const double th0 = theta_troc + rng.uniform(-35, 35) * kDeg;
            const double th1 = th0 + (rng.uniform(0, 1) < 0.5 ? -1 : 1) * rng.uniform(45, 70) * kDeg;
            // A careful surgeon grasps the flap about 1.3 mm inside the edge; the hard one takes the edge itself,
            // next to where the membrane is attached.
            auto grasp_rho = [&](double th) {
                return surgeon::membrane_outline_radius_mm(th) - (hard ? 0.15 : 1.3) + jit(0.05);
            };
            const double rho_g = grasp_rho(th0);
            const double grasp_h = 0.12 + jit(0.02);
            // Too hard: lifted high and fast, straight off the attached rim.
            const double pull = hard ? 0.3 + jit(0.1) : 1.2 + jit(0.1);
            const double lift = hard ? 2.5 + jit(0.1) : 0.3 + jit(0.05);
            const double pull_s = hard ? 0.5 : 2.0 + jit(0.2);
            add(0.0, above_membrane(0.5, th0 + kPi, 6.0), 0.0);
            double t = 0.9;
            for (int g = 0; g < 2; ++g) {
                const double th = g == 0 ? th0 : th1;
                const double rho = g == 0 ? rho_g : grasp_rho(th1);
                add(t, above_membrane(rho, th, 1.0), 0.0);                    // over the edge
                add(t + 0.5, above_membrane(rho, th, grasp_h), 0.0);          // down to it
                add(t + 0.8, above_membrane(rho, th, grasp_h), 1.0);          // close the jaws
                add(t + 1.1, above_membrane(rho - 0.1, th, 0.2), 1.0);        // lift the flap
                add(t + 1.1 + pull_s, above_membrane(rho - pull, th, lift), 1.0);  // pull along the surface
                add(t + 1.4 + pull_s, above_membrane(rho - pull, th, lift), 0.0);  // release
                t += 1.4 + pull_s + 0.7;
            }
            add(t + 0.5, above_membrane(0.0, th0, 4.0), 0.0);
        } else {
            // The port 0.1 mm in front of the vitreous membrane (the cutter reaches 0.15 mm), swept line by line with the pedal pressed.
            s.aim_port_ = true;
            const Eigen::Vector3d n = surgeon::kSheetNormal.normalized();
            const Eigen::Vector3d u = n.cross(Eigen::Vector3d::UnitY()).normalized(), v = n.cross(u);
            const double half = 0.5 * surgeon::kSheetSize_mm - 0.8;
            auto at = [&](double su, double sv, double off) { return surgeon::kSheetCentre_mm + su * u + sv * v + off * n; };
            const double gap = 0.1 + jit(0.02);
            add(0.0, at(-half, -half, 3.0), 0.0);
            add(0.8, at(-half, -half, gap), 0.0);
            double t = 1.0;
            add(t, at(-half, -half, gap), 0.85);
            const int lines = 5;
            for (int l = 0; l < lines; ++l) {
                const double a = -half + 2.0 * half * l / (lines - 1) + jit(0.05);
                const double end = l % 2 == 0 ? half : -half;
                add(t + 0.9, at(a, end + jit(0.1), gap + jit(0.02)), 0.85);
                t += 0.9;
                if (l + 1 < lines) {
                    add(t + 0.15, at(a + 2.0 * half / (lines - 1), end, gap), 0.85);
                    t += 0.15;
                }
            }
            add(t + 0.2, at(half, 0.0, gap), 0.0);
            add(t + 0.8, at(0.0, 0.0, 3.0), 0.0);
        }
        std::sort(s.path_.begin(), s.path_.end(), [](const Waypoint& x, const Waypoint& y) { return x.t_s < y.t_s; });
        // Tremor: physiological 8–12 Hz, about 10 µm, and a slower drift of about 20 µm.
        for (auto& axis : s.tremor_) {
            axis.push_back({0.010, rng.uniform(8, 12), rng.uniform(0, 2 * kPi)});
            axis.push_back({0.020, rng.uniform(0.5, 1.5), rng.uniform(0, 2 * kPi)});
        }
    }

    // Pedal: main axis pressed and released in cycles (surgery, fast), slow joystick axes.
    const double pf = name == "static" ? 0.0 : rng.uniform(0.3, 0.6);
    s.pedal0_base_ = name == "static" ? rng.uniform(0.0, 1.0) : 0.5;
    if (name != "static") s.pedal0_.push_back({0.8, pf, rng.uniform(0, 2 * kPi)});
    if (name != "static") {
        s.pedal1_.push_back({0.7, rng.uniform(0.05, 0.2), rng.uniform(0, 2 * kPi)});
        s.pedal2_.push_back({0.7, rng.uniform(0.05, 0.2), rng.uniform(0, 2 * kPi)});
    }

    // Eye: target rotation (what the surgeon pushes towards), the springs and damping do the rest.
    std::vector<Wave> eye_w[3];
    Eigen::Vector3d eye_bias(rng.uniform(-3, 3) * kDeg, rng.uniform(-3, 3) * kDeg, rng.uniform(-2, 2) * kDeg);
    for (int a = 0; a < 3; ++a)
        for (int w = 0; w < 2; ++w)
            eye_w[a].push_back({b.eye_amp / 1.5 * (a == 2 ? 0.5 : 1.0), rng.uniform(b.eye_f0, b.eye_f1) + 1e-9,
                                rng.uniform(0, 2 * kPi)});
    const double w0 = 2 * kPi * kEyeSpringHz, zeta = kEyeDamping;
    auto target = [&](double t) {
        return Eigen::Vector3d(eye_bias.x() + eval(eye_w[0], t), eye_bias.y() + eval(eye_w[1], t),
                               eye_bias.z() + eval(eye_w[2], t));
    };
    auto accel = [&](double t, const Eigen::Vector3d& th, const Eigen::Vector3d& om) -> Eigen::Vector3d {
        return w0 * w0 * (target(t) - th) - 2 * zeta * w0 * om;
    };
    if (name == "wand") {
        // A hand circling the eye with the wand: the marker centroid at distance rho from the eye centre (never
        // closer than the wand's half-length plus the eye and a marker, so no marker touches the eye), azimuth
        // turning steadily round the eye and elevation from 5° below to 55° above its equator (where the
        // instruments' markers are; lower, the wand would come so near a camera that its markers grow past 12 px);
        // the rod turns through all directions (azimuth turning, elevation a seeded tilt plus ±60° of waving).
        // Markers move at about 25 mm/s (up to ~80), as a hand moves a wand through a volume this small.
        if (!bodies.wand.present()) throw RigError("scenario: wand: bodies.json has no \"wand\"");
        s.wand_ = true;
        double sum = 0, reach = 0, marker_r = 0;
        for (const WandMarker& m : bodies.wand.markers) {
            sum += m.distance_mm;
            marker_r = std::max(marker_r, m.radius_mm);
        }
        s.wand_centroid_mm_ = sum / static_cast<double>(bodies.wand.markers.size());
        for (const WandMarker& m : bodies.wand.markers) reach = std::max(reach, std::fabs(m.distance_mm - s.wand_centroid_mm_));
        s.wand_clear_mm_ = bodies.eye.radius_mm + marker_r + reach + 1.0;
        const double sign = rng.uniform(0, 1) < 0.5 ? -1.0 : 1.0;
        s.wand_azimuth0_ = rng.uniform(0, 2 * kPi);  // of the position round the eye
        s.wand_azimuth_rate_ = sign * 2 * kPi / rng.uniform(10.0, 16.0);
        // wand_centre_: [0] distance (mm, above the least), [1] position azimuth waves (rad), [2] elevation (rad).
        for (int w = 0; w < 2; ++w) {
            s.wand_centre_[0].push_back({5.5, rng.uniform(0.15, 0.35), rng.uniform(0, 2 * kPi)});
            s.wand_centre_[1].push_back({0.35, rng.uniform(0.1, 0.3), rng.uniform(0, 2 * kPi)});
            s.wand_centre_[2].push_back({15 * kDeg, rng.uniform(0.1, 0.3), rng.uniform(0, 2 * kPi)});
            s.wand_azimuth_.push_back({0.6, rng.uniform(0.15, 0.4), rng.uniform(0, 2 * kPi)});
            s.wand_elevation_.push_back({30 * kDeg, rng.uniform(0.1, 0.35), rng.uniform(0, 2 * kPi)});
        }
        s.wand_centre0_mm_ = Eigen::Vector3d(rng.uniform(0, 2 * kPi), 25 * kDeg, rng.uniform(-1.0, 1.0) * kPi / 4);
    }

    s.eye_t0_s_ = -1.0;
    const int n = static_cast<int>(std::ceil((dur_s + 2.0) / s.eye_dt_s_)) + 2;
    s.eye_rot_.resize(n);
    s.eye_rate_.resize(n);
    Eigen::Vector3d th = target(s.eye_t0_s_), om = Eigen::Vector3d::Zero();
    const double h = s.eye_dt_s_;
    for (int i = 0; i < n; ++i) {
        const double t = s.eye_t0_s_ + i * h;
        s.eye_rot_[i] = th;
        s.eye_rate_[i] = om;
        // RK4 on (theta, omega).
        const Eigen::Vector3d k1x = om, k1v = accel(t, th, om);
        const Eigen::Vector3d k2x = om + 0.5 * h * k1v, k2v = accel(t + 0.5 * h, th + 0.5 * h * k1x, om + 0.5 * h * k1v);
        const Eigen::Vector3d k3x = om + 0.5 * h * k2v, k3v = accel(t + 0.5 * h, th + 0.5 * h * k2x, om + 0.5 * h * k2v);
        const Eigen::Vector3d k4x = om + h * k3v, k4v = accel(t + h, th + h * k3x, om + h * k3v);
        th += h / 6 * (k1x + 2 * k2x + 2 * k3x + k4x);
        om += h / 6 * (k1v + 2 * k2v + 2 * k3v + k4v);
    }
    return s;
}

Eigen::Vector3d Scenario::path_at(double t_s, double& pedal) const {
    if (t_s <= path_.front().t_s) {
        pedal = path_.front().pedal;
        return path_.front().p_eye_mm;
    }
    for (size_t i = 1; i < path_.size(); ++i) {
        if (t_s > path_[i].t_s) continue;
        const Waypoint& a = path_[i - 1];
        const Waypoint& b = path_[i];
        const double u = smoothstep(a.t_s, b.t_s, t_s);  // minimum-jerk profile between rests
        pedal = a.pedal + u * (b.pedal - a.pedal);
        return a.p_eye_mm + u * (b.p_eye_mm - a.p_eye_mm);
    }
    pedal = path_.back().pedal;
    return path_.back().p_eye_mm;
}

void Scenario::wand_state(double t_s, SceneState& st) const {
    // wand_centre0_mm_ holds (rod azimuth phase, position elevation base, rod elevation base), in rad.
    const double rho = wand_clear_mm_ + 11.0 + eval(wand_centre_[0], t_s);
    const double az = wand_azimuth0_ + wand_azimuth_rate_ * t_s + eval(wand_centre_[1], t_s);
    const double el = wand_centre0_mm_.y() + eval(wand_centre_[2], t_s);
    const Eigen::Vector3d centre =
        st.eye_center_rig_mm + rho * Eigen::Vector3d(std::cos(el) * std::cos(az), std::cos(el) * std::sin(az), std::sin(el));
    const double rod_az = wand_centre0_mm_.x() + 0.7 * wand_azimuth_rate_ * t_s + eval(wand_azimuth_, t_s);
    const double rod_el = wand_centre0_mm_.z() + eval(wand_elevation_, t_s);
    const Eigen::Vector3d axis(std::cos(rod_el) * std::cos(rod_az), std::cos(rod_el) * std::sin(rod_az), std::sin(rod_el));
    st.wand_present = true;
    st.wand_axis_rig = axis;
    st.wand_origin_rig_mm = centre - wand_centroid_mm_ * axis;
}

SceneState Scenario::state_at(double t_us) const {
    SceneState st;
    st.t_us = t_us;
    const double t = t_us * 1e-6;
    st.eye_center_rig_mm = bodies_.eye.center_rig_mm;
    if (wand_) {
        // The eye at rest (eye frame = rig frame), the pedal released, both instruments lifted 300 mm out of
        // their trocars with vertical shafts: 45° off every default camera's axis, well outside their views.
        wand_state(t, st);
        for (size_t k = 0; k < kinds_.size(); ++k) {
            InstrumentPose p;
            p.kind = kinds_[k];
            p.trocar = static_cast<int>(k);
            p.axis_eye = Eigen::Vector3d::UnitZ();
            p.insertion_mm = -300.0;
            p.tip_eye_mm = bodies_.eye.trocars.at(k).position_eye_mm - p.insertion_mm * p.axis_eye;
            st.instruments.push_back(p);
        }
        return st;
    }
    if (board_) st.board = board_->pose_at(t_us);

    // Eye rotation vector: cubic Hermite between RK4 samples.
    const double x = (t - eye_t0_s_) / eye_dt_s_;
    int i = static_cast<int>(std::floor(x));
    i = std::clamp(i, 0, static_cast<int>(eye_rot_.size()) - 2);
    const double u = std::clamp(x - i, 0.0, 1.0);
    const double h00 = 2 * u * u * u - 3 * u * u + 1, h10 = u * u * u - 2 * u * u + u;
    const double h01 = -2 * u * u * u + 3 * u * u, h11 = u * u * u - u * u;
    const Eigen::Vector3d th = h00 * eye_rot_[i] + h10 * eye_dt_s_ * eye_rate_[i] + h01 * eye_rot_[i + 1] +
                               h11 * eye_dt_s_ * eye_rate_[i + 1];
    const double ang = th.norm();
    st.q_eye_to_rig = ang > 0 ? Eigen::Quaterniond(Eigen::AngleAxisd(ang, th / ang)) : Eigen::Quaterniond::Identity();

    // Pedal.
    st.pedal.axes[0] = std::clamp(pedal0_base_ + eval(pedal0_, t), 0.0, 1.0);
    if (injection_) st.pedal.axes[0] = 0.8 * smoothstep(1.2, 2.0, t) * (1.0 - smoothstep(3.4, 3.6, t));
    st.pedal.axes[1] = std::clamp(eval(pedal1_, t), -1.0, 1.0);
    st.pedal.axes[2] = std::clamp(eval(pedal2_, t), -1.0, 1.0);
    st.pedal.buttons = (st.pedal.axes[1] > 0.5 ? 1u : 0u) | (st.pedal.axes[2] > 0.5 ? 2u : 0u);

    for (size_t k = 0; k < kinds_.size(); ++k) {
        const InstrumentMotion& m = motion_[k];
        const InstrumentBody& body = bodies_.instrument(kinds_[k]);
        InstrumentPose p;
        p.kind = kinds_[k];
        p.trocar = static_cast<int>(k);
        const Eigen::Vector3d troc = bodies_.eye.trocars.at(k).position_eye_mm;
        const Eigen::Vector3d n = troc.normalized();
        const Eigen::Vector3d e1 = n.cross(Eigen::Vector3d::UnitZ()).norm() > 1e-6
                                       ? n.cross(Eigen::Vector3d::UnitZ()).normalized()
                                       : Eigen::Vector3d::UnitX();
        const Eigen::Vector3d e2 = n.cross(e1);
        const double flick = m.flick_s < 1e29 ? 4.0 * kDeg * smoothstep(m.flick_s, m.flick_s + 0.1, t) : 0.0;
        const double tx = m.tilt_x0 + eval(m.tilt_x, t) + flick, ty = m.tilt_y0 + eval(m.tilt_y, t);
        const Eigen::Vector3d d_in = (-n + std::tan(tx) * e1 + std::tan(ty) * e2).normalized();
        // Keep the tip inside the eye: at most 90% of the chord along d_in.
        const double chord = 2.0 * bodies_.eye.radius_mm * (-d_in.dot(n));
        double ins = std::clamp(m.insertion0 + eval(m.insertion, t), 2.0, std::min(0.9 * chord, body.max_insertion_mm));
        if (injection_ && k == 0) {
            // The needle goes to the posterior wall and penetrates the retina (inner radius 11.5 mm) by 0.1 mm
            // after 1 s, then stays at that depth while the tilt waves slide it along the retina; a quick flick
            // at 3.0 s moves it fast along the retina (the tear-warning situation).
            const double r_tip = bodies_.eye.radius_mm - 0.4;
            const double b_ = troc.dot(d_in), c_ = troc.squaredNorm() - r_tip * r_tip;
            const double s_wall = -b_ + std::sqrt(std::max(0.0, b_ * b_ - c_));
            ins = s_wall - 1.5 * (1.0 - smoothstep(0.0, 1.0, t));
        }
        if (k == 0 && !path_.empty()) {
            // Synthetic surgeon: the scripted point plus tremor, reached through the trocar.
            double pedal = 0.0;
            Eigen::Vector3d target = path_at(t, pedal);
            for (int a = 0; a < 3; ++a) target[a] += eval(tremor_[a], t);
            Eigen::Vector3d tip = target;
            if (aim_port_) {
                // The side port is at `target`: solve for the tip (the port's offset turns with the shaft).
                for (int it = 0; it < 4; ++it) {
                    const Eigen::Vector3d z = (tip - troc).normalized();
                    tip = target - surgeon::kVitrectorPort_mm.x() * shaft_x(z) - surgeon::kVitrectorPort_mm.z() * z;
                }
            }
            // Never through the retina (a tissue instrument stays 80 µm clear of it), never past full insertion.
            const double r_max = surgeon::kRetinaRadius_mm - 0.08;
            if (tip.norm() > r_max) tip *= r_max / tip.norm();
            Eigen::Vector3d d = tip - troc;
            if (d.norm() > body.max_insertion_mm) tip = troc + d * (body.max_insertion_mm / d.norm());
            d = (tip - troc).normalized();
            p.insertion_mm = (tip - troc).norm();
            p.tip_eye_mm = tip;
            p.axis_eye = -d;
            st.pedal.axes[0] = std::clamp(pedal, 0.0, 1.0);
            p.jaw_opening = kinds_[k] == InstrumentKind::kForceps ? 1.0 - st.pedal.axes[0] : 0.0;
            st.instruments.push_back(p);
            continue;
        }
        const double retract = smoothstep(m.retract_start_s, m.retract_start_s + 0.15 * (m.retract_end_s - m.retract_start_s), t) *
                               (1.0 - smoothstep(m.retract_end_s - 0.15 * (m.retract_end_s - m.retract_start_s), m.retract_end_s, t));
        ins -= retract * 60.0;
        p.insertion_mm = ins;
        p.tip_eye_mm = troc + ins * d_in;
        p.axis_eye = -d_in;
        p.jaw_opening = kinds_[k] == InstrumentKind::kForceps ? 1.0 - st.pedal.axes[0] : 0.0;
        st.instruments.push_back(p);
    }
    return st;
}

}  // namespace eyesim::rig
