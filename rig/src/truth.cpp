#include "eyesim/rig/truth.hpp"

#include "eyesim/rig/error.hpp"

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include <cmath>

namespace eyesim::rig {

namespace {

using nlohmann::json;

json v3(const Eigen::Vector3d& v) { return json::array({v.x(), v.y(), v.z()}); }
json v2(const Eigen::Vector2d& v) { return json::array({v.x(), v.y()}); }

struct Parser {
    std::string where;
    [[noreturn]] void fail(const std::string& key, const std::string& why) const {
        throw RigError(fmt::format("{}: {}: {}", where, key, why));
    }
    const json& at(const json& j, const std::string& key_path, const char* key) const {
        if (!j.is_object() || !j.contains(key)) fail(key_path + key, "missing");
        return j.at(key);
    }
    double num(const json& j, const std::string& kp, const char* key) const {
        const json& v = at(j, kp, key);
        if (!v.is_number()) fail(kp + key, "not a number");
        const double d = v.get<double>();
        if (!std::isfinite(d)) fail(kp + key, "not finite");
        return d;
    }
    template <int N>
    Eigen::Matrix<double, N, 1> vec(const json& j, const std::string& kp, const char* key) const {
        const json& v = at(j, kp, key);
        if (!v.is_array() || v.size() != N) fail(kp + key, fmt::format("must be an array of {} numbers", N));
        Eigen::Matrix<double, N, 1> r;
        for (int i = 0; i < N; ++i) {
            if (!v[i].is_number()) fail(kp + key, "not a number");
            r[i] = v[i].get<double>();
            if (!std::isfinite(r[i])) fail(kp + key, "not finite");
        }
        return r;
    }
    const json& arr(const json& j, const std::string& kp, const char* key) const {
        const json& v = at(j, kp, key);
        if (!v.is_array()) fail(kp + key, "must be an array");
        return v;
    }
};

InstrumentKind kind_from(const Parser& p, const std::string& kp, const std::string& name) {
    for (int k = 0; k <= 4; ++k)
        if (name == instrument_kind_name(static_cast<InstrumentKind>(k))) return static_cast<InstrumentKind>(k);
    p.fail(kp, fmt::format("unknown instrument kind '{}'", name));
}

}  // namespace

std::string truth_to_json_line(const FieldTruth& t) {
    json j;
    j["field"] = t.field;
    j["t_us"] = t.t_us;
    json cams = json::array();
    for (const auto& c : t.cameras)
        cams.push_back({{"field", c.field}, {"parity", c.parity}, {"exposure_mid_us", c.exposure_mid_us},
                        {"exposure_us", c.exposure_us}, {"end_us", c.end_us}});
    j["cameras"] = cams;
    const Eigen::Quaterniond q = t.q_eye_to_rig;
    j["eye"] = {{"center_rig_mm", v3(t.eye_center_rig_mm)}, {"q_eye_to_rig", json::array({q.w(), q.x(), q.y(), q.z()})}};
    json ins = json::array();
    for (const auto& i : t.instruments)
        ins.push_back({{"kind", instrument_kind_name(i.kind)}, {"trocar", i.trocar}, {"tip_rig_mm", v3(i.tip_rig_mm)},
                       {"axis_rig", v3(i.axis_rig)}, {"tip_eye_mm", v3(i.tip_eye_mm)}, {"axis_eye", v3(i.axis_eye)},
                       {"insertion_mm", i.insertion_mm}, {"jaw_opening", i.jaw_opening}});
    j["instruments"] = ins;
    j["pedal"] = {{"axes", json::array({t.pedal.axes[0], t.pedal.axes[1], t.pedal.axes[2]})},
                  {"buttons", t.pedal.buttons}};
    json mk = json::array();
    for (const auto& m : t.markers) {
        json cams_m = json::array();
        for (const auto& c : m.cams) {
            json cj = {{"visible", c.visible}, {"projectable", c.projectable}, {"center_rig_mm", v3(c.center_rig_mm)},
                       {"radius_px", c.radius_px}, {"area_px", c.area_px}, {"occluded_fraction", c.occluded_fraction}};
            if (c.projectable) {
                cj["projected_px"] = v2(c.projected_px);
                cj["centroid_px"] = v2(c.centroid_px);
            }
            cams_m.push_back(std::move(cj));
        }
        mk.push_back({{"body", m.body}, {"id", m.id}, {"class", m.colour_class}, {"radius_mm", m.radius_mm},
                      {"center_rig_mm", v3(m.center_rig_mm)}, {"cams", cams_m}});
    }
    j["markers"] = mk;
    if (t.board) {
        const BoardTruth& b = *t.board;
        auto quat = [](const Eigen::Quaterniond& r) { return json::array({r.w(), r.x(), r.y(), r.z()}); };
        json bc = json::array();
        for (const auto& c : b.cams)
            bc.push_back({{"q_board_to_rig", quat(c.q_board_to_rig)}, {"origin_rig_mm", v3(c.origin_rig_mm)},
                          {"facing", c.facing}, {"corners_in_image", c.corners_in_image}, {"motion_px", c.motion_px}});
        j["board"] = {{"squares", json::array({b.squares_x, b.squares_y})}, {"square_mm", b.square_mm},
                      {"q_board_to_rig", quat(b.q_board_to_rig)}, {"origin_rig_mm", v3(b.origin_rig_mm)},
                      {"cams", bc}};
    }
    return j.dump();
}

FieldTruth truth_from_json_line(const std::string& line, const std::string& where) {
    Parser p{where};
    json j;
    try {
        j = json::parse(line);
    } catch (const json::parse_error& e) {
        p.fail("line", fmt::format("malformed JSON at byte {}", e.byte));
    }
    FieldTruth t;
    t.field = static_cast<int64_t>(p.num(j, "", "field"));
    t.t_us = p.num(j, "", "t_us");
    const json& cams = p.arr(j, "", "cameras");
    for (size_t i = 0; i < cams.size(); ++i) {
        const std::string kp = fmt::format("cameras[{}].", i);
        CameraFieldTruth c;
        c.field = static_cast<int64_t>(p.num(cams[i], kp, "field"));
        c.parity = static_cast<int>(p.num(cams[i], kp, "parity"));
        c.exposure_mid_us = p.num(cams[i], kp, "exposure_mid_us");
        c.exposure_us = p.num(cams[i], kp, "exposure_us");
        c.end_us = p.num(cams[i], kp, "end_us");
        t.cameras.push_back(c);
    }
    const json& eye = p.at(j, "", "eye");
    t.eye_center_rig_mm = p.vec<3>(eye, "eye.", "center_rig_mm");
    const Eigen::Vector4d q = p.vec<4>(eye, "eye.", "q_eye_to_rig");
    t.q_eye_to_rig = Eigen::Quaterniond(q[0], q[1], q[2], q[3]);
    const json& ins = p.arr(j, "", "instruments");
    for (size_t i = 0; i < ins.size(); ++i) {
        const std::string kp = fmt::format("instruments[{}].", i);
        InstrumentTruth it;
        const json& k = p.at(ins[i], kp, "kind");
        if (!k.is_string()) p.fail(kp + "kind", "not a string");
        it.kind = kind_from(p, kp + "kind", k.get<std::string>());
        it.trocar = static_cast<int>(p.num(ins[i], kp, "trocar"));
        it.tip_rig_mm = p.vec<3>(ins[i], kp, "tip_rig_mm");
        it.axis_rig = p.vec<3>(ins[i], kp, "axis_rig");
        it.tip_eye_mm = p.vec<3>(ins[i], kp, "tip_eye_mm");
        it.axis_eye = p.vec<3>(ins[i], kp, "axis_eye");
        it.insertion_mm = p.num(ins[i], kp, "insertion_mm");
        it.jaw_opening = p.num(ins[i], kp, "jaw_opening");
        t.instruments.push_back(it);
    }
    const json& pedal = p.at(j, "", "pedal");
    const Eigen::Vector3d axes = p.vec<3>(pedal, "pedal.", "axes");
    for (int i = 0; i < 3; ++i) t.pedal.axes[i] = axes[i];
    t.pedal.buttons = static_cast<uint32_t>(p.num(pedal, "pedal.", "buttons"));
    const json& mk = p.arr(j, "", "markers");
    for (size_t i = 0; i < mk.size(); ++i) {
        const std::string kp = fmt::format("markers[{}].", i);
        MarkerTruth m;
        const json& body = p.at(mk[i], kp, "body");
        if (!body.is_string()) p.fail(kp + "body", "not a string");
        m.body = body.get<std::string>();
        m.id = static_cast<int>(p.num(mk[i], kp, "id"));
        m.colour_class = static_cast<int>(p.num(mk[i], kp, "class"));
        m.radius_mm = p.num(mk[i], kp, "radius_mm");
        m.center_rig_mm = p.vec<3>(mk[i], kp, "center_rig_mm");
        const json& cm = p.arr(mk[i], kp, "cams");
        for (size_t c = 0; c < cm.size(); ++c) {
            const std::string kc = fmt::format("{}cams[{}].", kp, c);
            MarkerCameraTruth mc;
            const json& vis = p.at(cm[c], kc, "visible");
            if (!vis.is_boolean()) p.fail(kc + "visible", "not a boolean");
            mc.visible = vis.get<bool>();
            const json& pr = p.at(cm[c], kc, "projectable");
            if (!pr.is_boolean()) p.fail(kc + "projectable", "not a boolean");
            mc.projectable = pr.get<bool>();
            mc.center_rig_mm = p.vec<3>(cm[c], kc, "center_rig_mm");
            mc.radius_px = p.num(cm[c], kc, "radius_px");
            mc.area_px = p.num(cm[c], kc, "area_px");
            mc.occluded_fraction = p.num(cm[c], kc, "occluded_fraction");
            if (mc.projectable) {
                mc.projected_px = p.vec<2>(cm[c], kc, "projected_px");
                mc.centroid_px = p.vec<2>(cm[c], kc, "centroid_px");
            }
            m.cams.push_back(mc);
        }
        t.markers.push_back(std::move(m));
    }
    if (j.contains("board")) {
        const json& bj = j.at("board");
        BoardTruth b;
        const Eigen::Vector2d sq = p.vec<2>(bj, "board.", "squares");
        b.squares_x = static_cast<int>(sq[0]);
        b.squares_y = static_cast<int>(sq[1]);
        b.square_mm = p.num(bj, "board.", "square_mm");
        auto quat = [&](const json& o, const std::string& kp) {
            const Eigen::Vector4d r = p.vec<4>(o, kp, "q_board_to_rig");
            return Eigen::Quaterniond(r[0], r[1], r[2], r[3]);
        };
        b.q_board_to_rig = quat(bj, "board.");
        b.origin_rig_mm = p.vec<3>(bj, "board.", "origin_rig_mm");
        const json& bc = p.arr(bj, "board.", "cams");
        for (size_t c = 0; c < bc.size(); ++c) {
            const std::string kc = fmt::format("board.cams[{}].", c);
            BoardCameraTruth ct;
            ct.q_board_to_rig = quat(bc[c], kc);
            ct.origin_rig_mm = p.vec<3>(bc[c], kc, "origin_rig_mm");
            const json& f = p.at(bc[c], kc, "facing");
            if (!f.is_boolean()) p.fail(kc + "facing", "not a boolean");
            ct.facing = f.get<bool>();
            ct.corners_in_image = static_cast<int>(p.num(bc[c], kc, "corners_in_image"));
            ct.motion_px = p.num(bc[c], kc, "motion_px");
            b.cams.push_back(ct);
        }
        t.board = std::move(b);
    }
    return t;
}

std::vector<FieldTruth> read_truth(const std::string& path) {
    std::ifstream in(path);
    if (!in) throw RigError(fmt::format("{}: file: missing or unreadable", path));
    std::vector<FieldTruth> out;
    std::string line;
    int n = 0;
    while (std::getline(in, line)) {
        ++n;
        if (line.empty()) continue;
        out.push_back(truth_from_json_line(line, fmt::format("{}:{}", path, n)));
    }
    return out;
}

TruthWriter::TruthWriter(const std::string& path) : path_(path), out_(path, std::ios::binary | std::ios::trunc) {
    if (!out_) throw RigError(fmt::format("{}: file: cannot be created", path));
}

void TruthWriter::write(const FieldTruth& truth) {
    out_ << truth_to_json_line(truth) << '\n';
    if (!out_) throw RigError(fmt::format("{}: file: write failed", path_));
}

void TruthWriter::close() {
    if (out_.is_open()) {
        out_.flush();
        if (!out_) throw RigError(fmt::format("{}: file: write failed", path_));
        out_.close();
    }
}

}  // namespace eyesim::rig
