#include "eyesim/rig/scenario.hpp"

#include "eyesim/rig/error.hpp"

#include <fmt/format.h>

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

std::vector<std::string> scenario_names() { return {"static", "sweep", "surgery", "fast", "occlusion", "injection"}; }

double Scenario::eval(const std::vector<Wave>& waves, double t_s) {
    double v = 0;
    for (const Wave& w : waves) v += w.amp * std::sin(2 * kPi * w.freq_hz * t_s + w.phase);
    return v;
}

Scenario Scenario::make(const std::string& name, uint64_t seed, double duration_us, const Bodies& bodies) {
    const auto names = scenario_names();
    if (std::find(names.begin(), names.end(), name) == names.end())
        throw RigError(fmt::format(
            "scenario: name: unknown scenario '{}' (static, sweep, surgery, fast, occlusion, injection)", name));
    Scenario s;
    s.name_ = name;
    s.bodies_ = bodies;
    Rng rng{seed ^ hash_name(name)};
    const double dur_s = std::max(duration_us, 0.0) * 1e-6;

    InstrumentKind tissue = InstrumentKind::kForceps;
    if (name == "sweep") tissue = InstrumentKind::kPick;
    if (name == "fast") tissue = InstrumentKind::kVitrector;
    if (name == "occlusion" || name == "injection") tissue = InstrumentKind::kInjection;
    s.injection_ = name == "injection";
    s.kinds_ = {tissue, InstrumentKind::kLightPipe};
    (void)bodies.instrument(tissue);
    (void)bodies.instrument(InstrumentKind::kLightPipe);

    // Motion amplitudes (tilt in rad, insertion in mm) and frequency bands per scenario.
    struct Band { double tilt_amp, tilt_f0, tilt_f1, ins_amp, ins_f0, ins_f1, eye_amp, eye_f0, eye_f1; };
    Band b{};
    if (name == "static") b = {0, 0, 0, 0, 0, 0, 0, 0, 0};
    if (name == "sweep") b = {22 * kDeg, 0.04, 0.12, 6.0, 0.05, 0.10, 8 * kDeg, 0.03, 0.08};
    if (name == "surgery") b = {1.5 * kDeg, 0.3, 0.8, 0.8, 0.2, 0.6, 2 * kDeg, 0.1, 0.4};
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

SceneState Scenario::state_at(double t_us) const {
    SceneState st;
    st.t_us = t_us;
    const double t = t_us * 1e-6;
    st.eye_center_rig_mm = bodies_.eye.center_rig_mm;

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
