#include "eyesim/sim/collision/instrument.hpp"
#include "eyesim/sim/mesh.hpp"

#include <Eigen/Geometry>
#include <catch2/catch.hpp>

#include <cmath>
#include <map>

using namespace eyesim::sim;
using namespace eyesim::sim::collision;

namespace {

/// Every directed edge of a closed, consistently oriented part appears once, its reverse once.
bool part_is_closed_and_oriented(const Instrument& ins, size_t part) {
    std::map<std::pair<uint32_t, uint32_t>, int> directed;
    for (uint32_t t = ins.part_triangle_begin[part]; t < ins.part_triangle_begin[part + 1]; ++t)
        for (int k = 0; k < 3; ++k) ++directed[{ins.mesh.triangles[t][k], ins.mesh.triangles[t][(k + 1) % 3]}];
    for (const auto& [e, n] : directed) {
        if (n != 1) return false;
        auto it = directed.find({e.second, e.first});
        if (it == directed.end() || it->second != 1) return false;
    }
    return true;
}

double part_volume(const Instrument& ins, size_t part) {
    double v = 0;
    for (uint32_t t = ins.part_triangle_begin[part]; t < ins.part_triangle_begin[part + 1]; ++t) {
        const auto& tr = ins.mesh.triangles[t];
        v += double(ins.mesh.vertices_mm[tr[0]].dot(ins.mesh.vertices_mm[tr[1]].cross(ins.mesh.vertices_mm[tr[2]]))) / 6.0;
    }
    return v;
}

}  // namespace

TEST_CASE("procedural instruments are ~2k-triangle closed meshes with the tip at the origin", "[sim][collision]") {
    for (auto kind : {InstrumentKind::Forceps, InstrumentKind::Vitrector, InstrumentKind::Pick,
                      InstrumentKind::InjectionNeedle, InstrumentKind::LightPipe}) {
        const Instrument ins = make_instrument(kind);
        INFO(instrument_name(kind));
        CHECK(ins.kind == kind);
        CHECK(ins.mesh.triangle_count() >= 1500);
        CHECK(ins.mesh.triangle_count() <= 2500);
        CHECK(ins.vertex_part.size() == ins.mesh.vertex_count());
        REQUIRE(ins.part_count() >= 1);
        CHECK(ins.part_triangle_begin.back() == ins.mesh.triangle_count());
        for (size_t p = 0; p < ins.part_count(); ++p) {
            CHECK(part_is_closed_and_oriented(ins, p));
            CHECK(part_volume(ins, p) > 0.0);  // outward normals
        }
        // The tip is the front-most point (within the tessellation of a rounded end).
        float zmax = -1e9f;
        for (const Vec3f& v : ins.mesh.vertices_mm) zmax = std::max(zmax, v.z());
        CHECK(std::fabs(zmax) < 0.02f);
        // The shaft reaches back into the eye by about 12 mm.
        float zmin = 1e9f;
        for (const Vec3f& v : ins.mesh.vertices_mm) zmin = std::min(zmin, v.z());
        CHECK(zmin < -11.0f);
    }
}

TEST_CASE("forceps jaws open symmetrically about the hinge with the pedal angle", "[sim][collision]") {
    const Instrument f = make_forceps();
    REQUIRE(f.part_count() == 3);
    std::vector<Vec3f> v(f.mesh.vertex_count());
    for (float opening : {0.0f, 10.0f, 30.0f, 60.0f}) {
        f.articulate(opening, v);
        float max_a = -1e9f, min_b = 1e9f;
        for (size_t i = 0; i < v.size(); ++i) {
            // Rigid motion: distances to the hinge are preserved.
            CHECK((v[i] - f.hinge_local_mm).norm() == Approx((f.mesh.vertices_mm[i] - f.hinge_local_mm).norm()).margin(1e-5));
            if (f.vertex_part[i] == InstrumentPart::Shaft) CHECK(v[i] == f.mesh.vertices_mm[i]);
            if (f.vertex_part[i] == InstrumentPart::JawA) max_a = std::max(max_a, v[i].x());
            if (f.vertex_part[i] == InstrumentPart::JawB) min_b = std::min(min_b, v[i].x());
        }
        // The jaw tips (1.5 mm from the hinge) move to ±1.5·sin(θ/2) plus the jaw thickness at most.
        const float s = 1.5f * std::sin(0.5f * opening * 3.14159265f / 180.0f);
        CHECK(max_a >= s - 1e-4f);
        CHECK(max_a <= s + 0.17f);
        CHECK(min_b <= -s + 1e-4f);
        CHECK(max_a == Approx(-min_b).margin(1e-5));
    }
    PosedInstrument posed(make_forceps());
    const Eigen::Isometry3f pose = Eigen::Isometry3f(Eigen::Translation3f(1, 2, 3));
    posed.set_state(20.0f, pose);
    CHECK(posed.tip_eye_mm().isApprox(Vec3f(1, 2, 3)));
    CHECK(posed.opening_deg() == 20.0f);
}

TEST_CASE("retina hemisphere lines the posterior inner eye sphere with inward normals", "[sim][collision]") {
    const TriangleMesh m = make_retina_hemisphere(kEyeRadius_mm, 20, 64);
    CHECK(m.triangle_count() == size_t(64 * (2 * 20 - 1)));
    for (const Vec3f& v : m.vertices_mm) {
        CHECK(v.norm() == Approx(kEyeRadius_mm).epsilon(1e-5));
        CHECK(v.z() <= 1e-5f);
    }
    for (const auto& t : m.triangles) {
        const Vec3f a = m.vertices_mm[t[0]], b = m.vertices_mm[t[1]], c = m.vertices_mm[t[2]];
        CHECK((b - a).cross(c - a).dot(a + b + c) < 0.0f);
    }
    // Disc topology: V − E + F = 1.
    CHECK(long(m.vertex_count()) - long(m.edges.size()) + long(m.triangle_count()) == 1);
}
