#include "eyesim/sim/scenes/scene.hpp"

#include <nlohmann/json.hpp>

#include <cmath>
#include <fstream>
#include <set>
#include <sstream>

namespace eyesim::sim::scenes {
namespace {

using nlohmann::json;

/// Walks one JSON object with its key path, checking types and ranges and rejecting unknown keys.
class Obj {
public:
    Obj(const json& j, std::string path, const std::string& origin) : j_(j), path_(std::move(path)), origin_(origin) {
        if (!j_.is_object()) fail("", "must be an object");
    }
    ~Obj() = default;

    [[noreturn]] void fail(const std::string& key, const std::string& why) const {
        throw SceneError(origin_ + ": " + join(key) + ": " + why);
    }
    std::string join(const std::string& key) const {
        if (path_.empty()) return key.empty() ? "(top level)" : key;
        return key.empty() ? path_ : path_ + "." + key;
    }
    bool has(const char* key) { seen_.insert(key); return j_.contains(key); }

    std::string str(const char* key, const std::string& def, bool required = false) {
        if (!has(key)) {
            if (required) fail(key, "missing");
            return def;
        }
        if (!j_[key].is_string()) fail(key, "must be a string");
        return j_[key].get<std::string>();
    }
    float num(const char* key, float def, float lo, float hi, bool allow_inf = false) {
        if (!has(key)) return def;
        const json& v = j_[key];
        double d = 0;
        if (v.is_number()) d = v.get<double>();
        else if (allow_inf && v.is_string() && v.get<std::string>() == "inf") d = INFINITY;
        else fail(key, allow_inf ? "must be a number or \"inf\"" : "must be a number");
        if (std::isnan(d) || (!allow_inf && std::isinf(d))) fail(key, "must be finite");
        if (!std::isinf(d) && (d < lo || d > hi)) {
            std::ostringstream os;
            os << "value " << d << " out of range [" << lo << ", " << hi << "]";
            fail(key, os.str());
        }
        return float(d);
    }
    int integer(const char* key, int def, int lo, int hi) {
        if (!has(key)) return def;
        if (!j_[key].is_number_integer()) fail(key, "must be an integer");
        const long long v = j_[key].get<long long>();
        if (v < lo || v > hi)
            fail(key, "value " + std::to_string(v) + " out of range [" + std::to_string(lo) + ", " + std::to_string(hi) + "]");
        return int(v);
    }
    bool boolean(const char* key, bool def) {
        if (!has(key)) return def;
        if (!j_[key].is_boolean()) fail(key, "must be true or false");
        return j_[key].get<bool>();
    }
    Eigen::Vector3f vec3(const char* key, const Eigen::Vector3f& def, float lim) {
        if (!has(key)) return def;
        const json& v = j_[key];
        if (!v.is_array() || v.size() != 3) fail(key, "must be an array of 3 numbers");
        Eigen::Vector3f out;
        for (int i = 0; i < 3; ++i) {
            if (!v[size_t(i)].is_number()) fail(key, "must be an array of 3 numbers");
            const double d = v[size_t(i)].get<double>();
            if (!std::isfinite(d) || std::fabs(d) > lim) fail(key, "component " + std::to_string(i) + " must be finite and within ±" + std::to_string(int(lim)));
            out[i] = float(d);
        }
        return out;
    }
    const json* child(const char* key, json::value_t type) {
        if (!has(key)) return nullptr;
        if (j_[key].type() != type) fail(key, type == json::value_t::array ? "must be an array" : "must be an object");
        return &j_[key];
    }
    std::string child_path(const std::string& key) const { return join(key); }
    const std::string& origin() const { return origin_; }

    /// Rejects keys that were never asked for (typos must not be silently ignored).
    void finish() const {
        for (auto it = j_.begin(); it != j_.end(); ++it)
            if (!seen_.count(it.key())) fail(it.key(), "unknown key");
    }

private:
    const json& j_;
    std::string path_;
    const std::string& origin_;
    std::set<std::string> seen_;
};

template <class E, size_t N>
E pick(Obj& o, const char* key, const std::string& value, const std::pair<const char*, E> (&table)[N]) {
    std::string names;
    for (const auto& [name, e] : table) {
        if (value == name) return e;
        names += names.empty() ? name : std::string(", ") + name;
    }
    o.fail(key, "'" + value + "' is not one of: " + names);
}

constexpr std::pair<const char*, collision::InstrumentKind> kKinds[] = {
    {"forceps", collision::InstrumentKind::Forceps},
    {"vitrector", collision::InstrumentKind::Vitrector},
    {"pick", collision::InstrumentKind::Pick},
    {"injection_needle", collision::InstrumentKind::InjectionNeedle},
    {"light_pipe", collision::InstrumentKind::LightPipe}};
constexpr std::pair<const char*, ZcollMode> kModes[] = {
    {"off", ZcollMode::kOff}, {"push", ZcollMode::kPush}, {"boolean", ZcollMode::kBoolean}, {"suction", ZcollMode::kSuction}};
constexpr std::pair<const char*, InstrumentRole> kRoles[] = {{"tissue", InstrumentRole::kTissue},
                                                              {"light", InstrumentRole::kLight}};
constexpr std::pair<const char*, TissueKind> kTissues[] = {
    {"none", TissueKind::kNone}, {"membrane", TissueKind::kMembrane}, {"retina", TissueKind::kRetina}};
constexpr std::pair<const char*, MembraneShape> kShapesM[] = {{"epiretinal", MembraneShape::kEpiretinal},
                                                               {"flat", MembraneShape::kFlat}};
constexpr std::pair<const char*, collision::ConvexShape> kShapes[] = {
    {"sphere", collision::ConvexShape::Sphere}, {"box", collision::ConvexShape::Box},
    {"cylinder", collision::ConvexShape::Cylinder}, {"capsule", collision::ConvexShape::Capsule},
    {"cone", collision::ConvexShape::Cone}};

void parse_instruments(const json& arr, Obj& parent, Scene& s) {
    if (arr.empty()) parent.fail("instruments", "at least one instrument is needed");
    for (size_t i = 0; i < arr.size(); ++i) {
        Obj o(arr[i], parent.child_path("instruments[" + std::to_string(i) + "]"), parent.origin());
        InstrumentSpec in;
        in.kind = pick(o, "kind", o.str("kind", "", true), kKinds);
        const bool light = in.kind == collision::InstrumentKind::LightPipe;
        in.role = pick(o, "role", o.str("role", light ? "light" : "tissue"), kRoles);
        in.zcoll = pick(o, "zcoll", o.str("zcoll", "off"), kModes);
        in.cuts = o.boolean("cuts", false);
        in.pedal_threshold = o.num("pedal_threshold", 0.5f, 0.0f, 1.0f);
        in.active_from_s = o.num("active_from_s", 0.0f, 0.0f, 3600.0f);
        if (in.zcoll == ZcollMode::kSuction && in.kind != collision::InstrumentKind::Vitrector)
            o.fail("zcoll", "'suction' needs a vitrector");
        if (in.cuts && in.kind != collision::InstrumentKind::Vitrector) o.fail("cuts", "only a vitrector cuts");
        for (const auto& prev : s.instruments)
            if (prev.role == in.role && prev.active_from_s >= in.active_from_s)
                o.fail("active_from_s", "instruments of one role must be listed with increasing active_from_s");
        o.finish();
        s.instruments.push_back(in);
    }
}

void parse_collision(Obj& o, Scene& s) {
    CollisionSpec& c = s.collision;
    c.eye_sphere = o.boolean("eye_sphere", c.eye_sphere);
    c.eye_warn_distance_mm = o.num("eye_warn_distance_mm", c.eye_warn_distance_mm, 0.0f, 5.0f);
    c.zcoll_resolution_px = o.integer("zcoll_resolution_px", c.zcoll_resolution_px, 4, 1024);
    c.zcoll_half_width_mm = o.num("zcoll_half_width_mm", c.zcoll_half_width_mm, 0.05f, 10.0f);
    c.zcoll_ahead_mm = o.num("zcoll_ahead_mm", c.zcoll_ahead_mm, 0.0f, 10.0f);
    c.zcoll_behind_mm = o.num("zcoll_behind_mm", c.zcoll_behind_mm, 0.0f, 30.0f);
    c.suction_half_angle_deg = o.num("suction_half_angle_deg", c.suction_half_angle_deg, 1.0f, 80.0f);
    c.suction_length_mm = o.num("suction_length_mm", c.suction_length_mm, 0.1f, 10.0f);
    if (const json* arr = o.child("convex_objects", json::value_t::array)) {
        for (size_t i = 0; i < arr->size(); ++i) {
            Obj b((*arr)[i], o.child_path("convex_objects[" + std::to_string(i) + "]"), o.origin());
            collision::ConvexObject obj;
            obj.shape = pick(b, "shape", b.str("shape", "", true), kShapes);
            obj.size_mm = b.vec3("size_mm", Eigen::Vector3f(1, 1, 1), 30.0f);
            if ((obj.size_mm.array() < 0.0f).any() || obj.size_mm.x() <= 0.0f) b.fail("size_mm", "sizes must be positive");
            obj.object_to_eye = Eigen::Isometry3f::Identity();
            obj.object_to_eye.translation() = b.vec3("center_eye_mm", Eigen::Vector3f::Zero(), 30.0f);
            b.finish();
            c.convex_objects.push_back(obj);
        }
    }
    o.finish();
}

void parse_tissue(Obj& o, Scene& s) {
    TissueSpec& t = s.tissue;
    t.kind = pick(o, "kind", o.str("kind", "none", true), kTissues);
    const bool anchored = o.has("anchor_ahead_of_tip_mm");
    if (anchored) t.anchor_ahead_of_tip_mm = o.num("anchor_ahead_of_tip_mm", 0.0f, -5.0f, 5.0f);
    t.shape = pick(o, "shape", o.str("shape", anchored ? "flat" : "epiretinal"), kShapesM);
    if (anchored && t.shape != MembraneShape::kFlat) o.fail("anchor_ahead_of_tip_mm", "needs shape 'flat'");
    if (t.shape == MembraneShape::kFlat) {
        t.width_mm = 6.0f;
        t.center_eye_mm = {0.0f, 0.0f, -10.5f};
    }
    t.triangles = o.integer("triangles", t.triangles, 50, 20000);
    t.width_mm = o.num("width_mm", t.width_mm, 0.5f, 20.0f);
    t.center_eye_mm = o.vec3("center_eye_mm", t.center_eye_mm, 12.0f);
    if (t.shape == MembraneShape::kEpiretinal && t.center_eye_mm.norm() < 1e-3f)
        o.fail("center_eye_mm", "must give a direction (not the eye centre)");
    t.normal_eye = o.vec3("normal_eye", t.normal_eye, 10.0f);
    if (t.normal_eye.norm() < 1e-3f) o.fail("normal_eye", "must not be zero");
    if (t.shape != MembraneShape::kFlat && o.has("normal_eye")) o.fail("normal_eye", "only a flat membrane has one");
    t.outline_irregularity = o.num("outline_irregularity", t.outline_irregularity, 0.0f, 0.5f);
    t.outline_seed = o.integer("outline_seed", t.outline_seed, 0, 1 << 30);
    t.lift_threshold_mm = o.num("lift_threshold_mm", t.lift_threshold_mm, 0.01f, 5.0f);
    t.anchor_to_port = o.boolean("anchor_to_port", false);
    if (t.anchor_to_port && !t.anchor_ahead_of_tip_mm) o.fail("anchor_to_port", "needs anchor_ahead_of_tip_mm");
    t.retina_rings = o.integer("retina_rings", t.retina_rings, 2, 200);
    t.retina_segments = o.integer("retina_segments", t.retina_segments, 6, 400);
    const std::string integ = o.str("integrator", "paper-euler");
    if (!tissue::parse_integrator(integ, t.integrator))
        o.fail("integrator", "'" + integ + "' is not one of: paper-euler, symplectic-euler, implicit-euler, xpbd");
    t.substeps = o.integer("substeps", t.substeps, 1, 1000);
    if (const json* m = o.child("material", json::value_t::object)) {
        Obj mo(*m, o.child_path("material"), o.origin());
        auto& mat = t.material;
        mat.areal_density_mg_per_mm2 = mo.num("areal_density_mg_per_mm2", mat.areal_density_mg_per_mm2, 1e-6f, 1e3f);
        mat.edge_stiffness_nN_per_mm = mo.num("edge_stiffness_nN_per_mm", mat.edge_stiffness_nN_per_mm, 0.0f, 1e9f);
        mat.edge_damping_nN_s_per_mm = mo.num("edge_damping_nN_s_per_mm", mat.edge_damping_nN_s_per_mm, 0.0f, 1e9f);
        mat.bending_stiffness_nN_per_mm = mo.num("bending_stiffness_nN_per_mm", mat.bending_stiffness_nN_per_mm, 0.0f, 1e9f);
        mat.bending_damping_nN_s_per_mm = mo.num("bending_damping_nN_s_per_mm", mat.bending_damping_nN_s_per_mm, 0.0f, 1e9f);
        mat.rest_length_scale = mo.num("rest_length_scale", mat.rest_length_scale, 0.1f, 2.0f);
        mo.finish();
    }
    if (const json* r = o.child("rules", json::value_t::object)) {
        Obj ro(*r, o.child_path("rules"), o.origin());
        auto& p = t.rules;
        constexpr float kBig = 1e12f;
        p.a_max_mm_per_s2 = ro.num("a_max_mm_per_s2", p.a_max_mm_per_s2, 0.0f, kBig, true);
        p.v_max_mm_per_s = ro.num("v_max_mm_per_s", p.v_max_mm_per_s, 0.0f, kBig, true);
        p.p_tear_percent = ro.num("p_tear_percent", p.p_tear_percent, 0.0f, kBig, true);
        p.drag_per_s = ro.num("drag_per_s", p.drag_per_s, 0.0f, 1e6f);
        p.lift_off_force_nN = ro.num("lift_off_force_nN", p.lift_off_force_nN, 0.0f, kBig, true);
        p.detach_pressure_min = ro.num("detach_pressure_min", p.detach_pressure_min, 0.0f, 1e6f);
        p.detach_radius_mm_per_pressure = ro.num("detach_radius_mm_per_pressure", p.detach_radius_mm_per_pressure, 0.0f, 100.0f);
        p.injection_force_nN_per_pressure = ro.num("injection_force_nN_per_pressure", p.injection_force_nN_per_pressure, 0.0f, 1e9f);
        p.tear_warning_speed_mm_per_s = ro.num("tear_warning_speed_mm_per_s", p.tear_warning_speed_mm_per_s, 0.0f, kBig, true);
        ro.finish();
    }
    o.finish();
}

void parse_scoring(Obj& o, Scene& s) {
    ScoringSpec& r = s.scoring;
    auto opt = [&](const char* key, std::optional<double>& v, float hi) {
        if (o.has(key)) v = o.num(key, 0.0f, 0.0f, hi);
    };
    opt("min_grabs", r.min_grabs, 1e6f);
    opt("min_peeled_percent", r.min_peeled_percent, 100.0f);
    opt("min_removed_mm2", r.min_removed_mm2, 1e4f);
    opt("min_nodes_detached", r.min_nodes_detached, 1e7f);
    opt("max_lift_off_warnings", r.max_lift_off_warnings, 1e9f);
    opt("max_tear_warnings", r.max_tear_warnings, 1e9f);
    opt("max_retina_contacts", r.max_retina_contacts, 1e9f);
    opt("max_object_contacts", r.max_object_contacts, 1e9f);
    opt("max_time_s", r.max_time_s, 1e6f);
    o.finish();
}

}  // namespace

bool Scene::needs_deformation() const {
    if (!needs_tissue()) return false;
    for (const auto& i : instruments)
        if (i.zcoll == ZcollMode::kPush || i.zcoll == ZcollMode::kSuction) return true;
    return false;
}

const InstrumentSpec* Scene::instrument(InstrumentRole role, float t_s) const {
    const InstrumentSpec* best = nullptr;
    for (const auto& i : instruments)
        if (i.role == role && (i.active_from_s <= t_s || best == nullptr)) best = &i;
    return best;
}

Scene parse_scene(const std::string& json_text, const std::string& origin) {
    json j;
    try {
        j = json::parse(json_text);
    } catch (const json::parse_error& e) {
        throw SceneError(origin + ": not valid JSON (byte " + std::to_string(e.byte) + ")");
    }
    Scene s;
    Obj top(j, "", origin);
    s.name = top.str("name", "", true);
    if (s.name.empty()) top.fail("name", "must not be empty");
    s.description = top.str("description", "");
    s.scenario = top.str("scenario", s.scenario);
    s.duration_s = top.num("duration_s", s.duration_s, 0.1f, 3600.0f);
    if (const json* arr = top.child("instruments", json::value_t::array)) parse_instruments(*arr, top, s);
    else top.fail("instruments", "missing");
    if (const json* c = top.child("collision", json::value_t::object)) {
        Obj co(*c, "collision", origin);
        parse_collision(co, s);
    }
    if (const json* t = top.child("tissue", json::value_t::object)) {
        Obj to(*t, "tissue", origin);
        parse_tissue(to, s);
    }
    if (const json* sc = top.child("scoring", json::value_t::object)) {
        Obj so(*sc, "scoring", origin);
        parse_scoring(so, s);
    }
    top.finish();
    for (const auto& in : s.instruments)
        if (in.zcoll != ZcollMode::kOff && !s.needs_tissue())
            top.fail("instruments", std::string("zcoll '") + to_string(in.zcoll) + "' needs a tissue");
    return s;
}

Scene load_scene(const std::string& path) {
    std::ifstream in(path, std::ios::binary);
    if (!in) throw SceneError(path + ": cannot open scene file");
    std::ostringstream ss;
    ss << in.rdbuf();
    return parse_scene(ss.str(), path);
}

const char* to_string(ZcollMode m) {
    switch (m) {
        case ZcollMode::kOff: return "off";
        case ZcollMode::kPush: return "push";
        case ZcollMode::kBoolean: return "boolean";
        case ZcollMode::kSuction: return "suction";
    }
    return "?";
}

const char* to_string(TissueKind k) {
    switch (k) {
        case TissueKind::kNone: return "none";
        case TissueKind::kMembrane: return "membrane";
        case TissueKind::kRetina: return "retina";
    }
    return "?";
}

}  // namespace eyesim::sim::scenes
