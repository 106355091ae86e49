#include "eyesim/rig/bodies.hpp"

#include "eyesim/rig/error.hpp"

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include <cmath>
#include <fstream>
#include <stdexcept>

namespace eyesim::rig {

const char* instrument_kind_name(InstrumentKind kind) noexcept {
    switch (kind) {
        case InstrumentKind::kPick: return "pick";
        case InstrumentKind::kForceps: return "forceps";
        case InstrumentKind::kVitrector: return "vitrector";
        case InstrumentKind::kLightPipe: return "light_pipe";
        case InstrumentKind::kInjection: return "injection";
    }
    return "unknown";
}

std::array<uint8_t, 3> marker_class_rgb(int colour_class) {
    switch (colour_class) {
        case 1: return {220, 40, 40};
        case 2: return {40, 200, 60};
        case 3: return {40, 80, 220};
        case 4: return {230, 210, 40};
        default: throw std::out_of_range(fmt::format("marker colour class {} not in 1..4", colour_class));
    }
}

const InstrumentBody& Bodies::instrument(InstrumentKind kind) const {
    for (const auto& b : instruments)
        if (b.kind == kind) return b;
    throw std::out_of_range(fmt::format("bodies: no instrument '{}'", instrument_kind_name(kind)));
}

namespace {

using nlohmann::json;

constexpr double kMaxLengthMm = 10000.0;

struct Reader {
    std::string path;
    [[noreturn]] void fail(const std::string& ptr, const std::string& why) const {
        throw RigError(fmt::format("{}: {}: {}", path, ptr, why));
    }
    const json& at(const json& j, const std::string& ptr, const char* key) const {
        if (!j.is_object() || !j.contains(key)) fail(ptr + "/" + key, "missing");
        return j.at(key);
    }
    double num(const json& j, const std::string& ptr, const char* key) const {
        const json& v = at(j, ptr, key);
        if (!v.is_number()) fail(ptr + "/" + key, "not a number");
        const double d = v.get<double>();
        if (!std::isfinite(d)) fail(ptr + "/" + key, "not finite");
        // Lengths are mm on a bench rig; beyond 10 m a value is a typo, and squares of it would overflow.
        if (std::abs(d) > kMaxLengthMm) fail(ptr + "/" + key, fmt::format("out of range, |{}| > {} mm", d, kMaxLengthMm));
        return d;
    }
    double positive(const json& j, const std::string& ptr, const char* key) const {
        const double d = num(j, ptr, key);
        if (!(d > 0)) fail(ptr + "/" + key, fmt::format("must be positive, got {}", d));
        return d;
    }
    int colour(const json& j, const std::string& ptr) const {
        const double d = num(j, ptr, "class");
        if (d != std::floor(d) || d < 1 || d > 4) fail(ptr + "/class", fmt::format("must be 1..4, got {}", d));
        return static_cast<int>(d);
    }
    Eigen::Vector3d vec3(const json& j, const std::string& ptr, const char* key) const {
        const json& v = at(j, ptr, key);
        if (!v.is_array() || v.size() != 3) fail(ptr + "/" + key, "must be an array of 3 numbers");
        Eigen::Vector3d r;
        for (int i = 0; i < 3; ++i) {
            if (!v[i].is_number()) fail(fmt::format("{}/{}/{}", ptr, key, i), "not a number");
            r[i] = v[i].get<double>();
            if (!std::isfinite(r[i])) fail(fmt::format("{}/{}/{}", ptr, key, i), "not finite");
            if (std::abs(r[i]) > kMaxLengthMm)
                fail(fmt::format("{}/{}/{}", ptr, key, i), fmt::format("out of range, |{}| > {} mm", r[i], kMaxLengthMm));
        }
        return r;
    }
    const json& array(const json& j, const std::string& ptr, const char* key) const {
        const json& v = at(j, ptr, key);
        if (!v.is_array()) fail(ptr + "/" + key, "must be an array");
        return v;
    }
};

}  // namespace

Bodies load_bodies(const std::string& path) {
    Reader rd{path};
    std::ifstream in(path);
    if (!in) rd.fail("file", "missing or unreadable");
    json doc;
    try {
        doc = json::parse(in);
    } catch (const json::parse_error& e) {
        rd.fail("file", fmt::format("malformed JSON at byte {}", e.byte));
    }
    Bodies b;
    const json& eye = rd.at(doc, "", "eye");
    b.eye.center_rig_mm = rd.vec3(eye, "/eye", "center_rig_mm");
    b.eye.radius_mm = rd.positive(eye, "/eye", "radius_mm");
    const json& em = rd.array(eye, "/eye", "markers");
    for (size_t i = 0; i < em.size(); ++i) {
        const std::string p = fmt::format("/eye/markers/{}", i);
        EyeMarker m;
        m.id = static_cast<int>(i);
        m.colour_class = rd.colour(em[i], p);
        m.position_eye_mm = rd.vec3(em[i], p, "position_eye_mm");
        m.radius_mm = rd.positive(em[i], p, "radius_mm");
        b.eye.markers.push_back(m);
    }
    // The eye's pose needs three markers; fewer and it would never be measured.
    if (b.eye.markers.size() < 3) rd.fail("/eye/markers", fmt::format("needs at least 3 markers, has {}", b.eye.markers.size()));
    const json& tr = rd.array(eye, "/eye", "trocars");
    for (size_t i = 0; i < tr.size(); ++i) {
        Trocar t;
        t.id = static_cast<int>(i);
        t.position_eye_mm = rd.vec3(tr[i], fmt::format("/eye/trocars/{}", i), "position_eye_mm");
        b.eye.trocars.push_back(t);
    }
    if (b.eye.trocars.size() < 2) rd.fail("/eye/trocars", "needs two trocars");
    const json& ins = rd.array(doc, "", "instruments");
    for (size_t i = 0; i < ins.size(); ++i) {
        const std::string p = fmt::format("/instruments/{}", i);
        InstrumentBody ib;
        const json& kind = rd.at(ins[i], p, "kind");
        if (!kind.is_string()) rd.fail(p + "/kind", "not a string");
        const std::string k = kind.get<std::string>();
        bool found = false;
        for (int kk = 0; kk <= 4; ++kk)
            if (k == instrument_kind_name(static_cast<InstrumentKind>(kk))) {
                ib.kind = static_cast<InstrumentKind>(kk);
                found = true;
            }
        if (!found) rd.fail(p + "/kind", fmt::format("unknown instrument kind '{}'", k));
        ib.name = k;
        ib.shaft_radius_mm = rd.positive(ins[i], p, "shaft_radius_mm");
        ib.shaft_length_mm = rd.positive(ins[i], p, "shaft_length_mm");
        ib.tip_offset_mm = rd.num(ins[i], p, "tip_offset_mm");
        ib.max_insertion_mm = rd.positive(ins[i], p, "max_insertion_mm");
        const json& mk = rd.array(ins[i], p, "markers");
        for (size_t j = 0; j < mk.size(); ++j) {
            const std::string pm = fmt::format("{}/markers/{}", p, j);
            InstrumentMarker m;
            m.id = static_cast<int>(j);
            m.colour_class = rd.colour(mk[j], pm);
            m.distance_from_tip_mm = rd.positive(mk[j], pm, "distance_from_tip_mm");
            m.radius_mm = rd.positive(mk[j], pm, "radius_mm");
            ib.markers.push_back(m);
        }
        // Acquiring an instrument takes all its markers and at least two define its axis.
        if (ib.markers.size() < 2)
            rd.fail(p + "/markers", fmt::format("needs at least 2 markers, has {}", ib.markers.size()));
        b.instruments.push_back(ib);
    }
    if (doc.contains("wand")) {
        const json& w = doc.at("wand");
        const json& wm = rd.array(w, "/wand", "markers");
        for (size_t j = 0; j < wm.size(); ++j) {
            const std::string pm = fmt::format("/wand/markers/{}", j);
            WandMarker m;
            m.id = static_cast<int>(j);
            m.colour_class = rd.colour(wm[j], pm);
            m.distance_mm = rd.num(wm[j], pm, "distance_mm");
            m.radius_mm = rd.positive(wm[j], pm, "radius_mm");
            // Marker 0 defines the wand frame's origin; the order along the rod is what tells the ends apart.
            if (j == 0 && m.distance_mm != 0.0) rd.fail(pm + "/distance_mm", fmt::format("must be 0 for marker 0, got {}", m.distance_mm));
            if (j > 0 && !(m.distance_mm > b.wand.markers.back().distance_mm))
                rd.fail(pm + "/distance_mm", fmt::format("must exceed the previous marker's {}, got {}",
                                                         b.wand.markers.back().distance_mm, m.distance_mm));
            b.wand.markers.push_back(m);
        }
        if (b.wand.markers.size() < 2)
            rd.fail("/wand/markers", fmt::format("needs at least 2 markers, has {}", b.wand.markers.size()));
    }
    return b;
}

std::string default_bodies_path() { return std::string(EYESIM_RIG_SOURCE_DIR) + "/scenes/bodies.json"; }

}  // namespace eyesim::rig
