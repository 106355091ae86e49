#include "eyesim/sim/collision/exact.hpp"
#include "eyesim/sim/collision/eye_sphere.hpp"
#include "eyesim/sim/collision/zcoll.hpp"

#include "alloc_counter.hpp"
#include "shapes.hpp"

#include <catch2/catch.hpp>

#include <cmath>
#include <random>

using namespace eyesim::sim;
using namespace eyesim::sim::collision;
using namespace eyesim::sim::collision::testing;


namespace {

constexpr float kSphereR = 1.0f;

/// The paper's Fig. 7 set-up: a 4×4 mm, 3042-triangle plane membrane at z = 0, a body pushed along −z.
struct PlaneScene {
    TriangleMesh membrane = make_membrane_patch(4.0f, 4.0f, kPatch3k.nx, kPatch3k.ny);
    Vec3f tip{0.031f, 0.017f, -0.3f};
    Eigen::Isometry3f pose() const { return pose_at(tip, Vec3f(0, 0, -1)); }
};

/// Camera-frame sample position of pixel (x, y) on the near plane, in the eye frame.
Vec3f pixel_on_camera_plane(const ZcollView& v, int x, int y) {
    const float r = float(v.resolution_px);
    const float cx = ((float(x) + 0.5f) / r * 2.0f - 1.0f) * v.half_width_mm;
    const float cy = ((float(y) + 0.5f) / r * 2.0f - 1.0f) * v.half_width_mm;
    return v.origin_eye_mm + v.camera_to_eye * Vec3f(cx, cy, 0);
}

/// 2D distance from point p to triangle (a, b, c) in the z = 0 plane (0 inside).
float distance_to_triangle_2d(const Eigen::Vector2f& p, const Eigen::Vector2f& a, const Eigen::Vector2f& b,
                              const Eigen::Vector2f& c) {
    auto cross = [](const Eigen::Vector2f& u, const Eigen::Vector2f& w) { return u.x() * w.y() - u.y() * w.x(); };
    const float d0 = cross(b - a, p - a), d1 = cross(c - b, p - b), d2 = cross(a - c, p - c);
    if ((d0 >= 0 && d1 >= 0 && d2 >= 0) || (d0 <= 0 && d1 <= 0 && d2 <= 0)) return 0.0f;
    auto seg = [](const Eigen::Vector2f& q, const Eigen::Vector2f& s, const Eigen::Vector2f& e) {
        const Eigen::Vector2f d = e - s;
        const float t = std::clamp((q - s).dot(d) / d.squaredNorm(), 0.0f, 1.0f);
        return (s + t * d - q).norm();
    };
    return std::min({seg(p, a, b), seg(p, b, c), seg(p, c, a)});
}

/// First hit of the ray o + t·d (t ≥ 0) with the posed instrument; +inf when none.
float ray_cast(const Vec3f& o, const Vec3f& d, const Instrument& ins, const std::vector<Vec3f>& v_eye) {
    float best = std::numeric_limits<float>::infinity();
    for (const auto& t : ins.mesh.triangles) {
        const Eigen::Vector3d v0 = v_eye[t[0]].cast<double>(), e1 = (v_eye[t[1]] - v_eye[t[0]]).cast<double>(),
                              e2 = (v_eye[t[2]] - v_eye[t[0]]).cast<double>();
        const Eigen::Vector3d h = d.cast<double>().cross(e2);
        const double det = e1.dot(h);
        if (std::fabs(det) < 1e-15) continue;
        const Eigen::Vector3d s = o.cast<double>() - v0;
        const double u = s.dot(h) / det;
        if (u < 0 || u > 1) continue;
        const Eigen::Vector3d q = s.cross(e1);
        const double w = d.cast<double>().dot(q) / det;
        if (w < 0 || u + w > 1) continue;
        const double tt = e2.dot(q) / det;
        if (tt >= 0 && tt < best) best = float(tt);
    }
    return best;
}

std::vector<Vec3f> posed_vertices(const PosedInstrument& p) {
    std::vector<Vec3f> v;
    for (const Vec3f& q : p.vertices_local_mm()) v.push_back(p.instrument_to_eye() * q);
    return v;
}

}  // namespace

TEST_CASE("Eq. 1 on hand-computed deformation vector sets", "[sim][collision][zcoll]") {
    const Vec3f a[] = {{0, 0, -1}, {0, 0, -0.5f}};
    CHECK(eq1_push_vector(a).isApprox(Vec3f(0, 0, -1)));
    const Vec3f b[] = {{1, 0, 0}, {0, 1, 0}};
    CHECK(eq1_push_vector(b).isApprox(Vec3f(std::sqrt(0.5f), std::sqrt(0.5f), 0)));
    // Length from the longest, direction from the (unnormalised) sum: (3,0,0)+(0,0,1) → |v| = 3.
    const Vec3f c[] = {{3, 0, 0}, {0, 0, 1}};
    CHECK(eq1_push_vector(c).isApprox(Vec3f(3, 0, 1).normalized() * 3.0f));
    const Vec3f d[] = {{1, 0, 0}, {-1, 0, 0}};
    CHECK(eq1_push_vector(d) == Vec3f::Zero());  // cancelling set: no direction
    CHECK(eq1_push_vector(std::span<const Vec3f>{}) == Vec3f::Zero());
}

TEST_CASE("Fig. 7: sphere pushed into a plane membrane gives the analytic penetration depths",
          "[sim][collision][zcoll]") {
    PlaneScene s;
    const float h = 0.3f;
    PosedInstrument sphere(sphere_body(kSphereR));
    sphere.set_state(0.0f, s.pose());
    ZcollConfig cfg;
    cfg.resolution_px = 64;
    ZcollEngine engine(s.membrane, cfg);
    const ZcollView view = make_tip_view(s.pose(), 1.2f, 0.5f, 2.5f, 64);
    const ZcollResult& r = engine.push(s.membrane.vertices_mm, sphere, view);
    REQUIRE(r.colliding);
    CHECK_FALSE(r.gated_out);
    CHECK(r.pi_convex);
    CHECK(r.multi_layer_pixels == 0);
    // Penetration below a point at radius ρ from the centre: h − R + √(R² − ρ²). Tessellation sagitta of the
    // 64-segment sphere ≈ 5 µm.
    const Vec3f centre(s.tip.x(), s.tip.y(), 0);
    size_t expected_pixels = 0;
    for (int y = 0; y < 64; ++y)
        for (int x = 0; x < 64; ++x) {
            const Vec3f p = pixel_on_camera_plane(view, x, y);
            const float rho = Eigen::Vector2f(p.x() - centre.x(), p.y() - centre.y()).norm();
            if (rho < kSphereR && h - kSphereR + std::sqrt(kSphereR * kSphereR - rho * rho) > 0.01f) ++expected_pixels;
        }
    size_t deep = 0;
    for (const ZcollFeature& f : r.features) {
        const Vec3f p = pixel_on_camera_plane(view, f.x_px, f.y_px);
        const float rho = Eigen::Vector2f(p.x() - centre.x(), p.y() - centre.y()).norm();
        const float analytic = h - kSphereR + std::sqrt(std::max(0.0f, kSphereR * kSphereR - rho * rho));
        CHECK(-f.depth_delta_mm == Approx(analytic).margin(0.008));
        deep += analytic > 0.01f;
    }
    CHECK(deep == expected_pixels);  // every clearly penetrated pixel is found
    // Eq. 1 node vectors: along the push direction (−z), length = max |d| of the node's adjacent triangles.
    REQUIRE(r.pushed_nodes.size() == r.node_push_eye_mm.size());
    REQUIRE_FALSE(r.pushed_nodes.empty());
    std::vector<float> tri_max(s.membrane.triangle_count(), 0.0f);
    for (const ZcollFeature& f : r.features) tri_max[f.id] = std::max(tri_max[f.id], -f.depth_delta_mm);
    for (size_t k = 0; k < r.pushed_nodes.size(); ++k) {
        const uint32_t v = r.pushed_nodes[k];
        float expect = 0;
        for (uint32_t i = s.membrane.vertex_triangle_begin[v]; i < s.membrane.vertex_triangle_begin[v + 1]; ++i)
            expect = std::max(expect, tri_max[s.membrane.vertex_triangles[i]]);
        const Vec3f push = r.node_push_eye_mm[k];
        CHECK(push.norm() == Approx(expect).margin(1e-6));
        CHECK(push.normalized().z() == Approx(-1.0f).margin(1e-5));
        CHECK(push.norm() <= h + 0.01f);
    }
}

TEST_CASE("at R = 256 the colliding triangles equal the exact set up to sub-pixel slivers",
          "[sim][collision][zcoll]") {
    PlaneScene s;
    const float h = 0.3f;
    PosedInstrument sphere(sphere_body(kSphereR));
    sphere.set_state(0.0f, s.pose());
    ZcollConfig cfg;
    cfg.resolution_px = 256;
    ZcollEngine engine(s.membrane, cfg);
    const ZcollView view = make_tip_view(s.pose(), 1.2f, 0.5f, 2.5f, 256);
    const ZcollResult& r = engine.push(s.membrane.vertices_mm, sphere, view);
    const auto exact = brute_force_colliding(s.membrane.vertices_mm, s.membrane.triangles, sphere.instrument(),
                                             sphere.vertices_local_mm(), s.pose());
    REQUIRE(exact.size() > 100);
    const std::vector<uint32_t> got(r.colliding_triangles.begin(), r.colliding_triangles.end());
    const size_t common = intersection_size(got, exact);
    INFO("zcoll " << got.size() << " exact " << exact.size() << " common " << common);
    // Radius of the cut circle and the pixel size: a triangle can be missed only when the part of it inside
    // the circle contains no sample: a sliver or a corner wedge, never deeper than 2 pixels into the circle.
    const float cut = std::sqrt(kSphereR * kSphereR - (kSphereR - h) * (kSphereR - h));
    const float px = view.pixel_mm();
    const Eigen::Vector2f c2(s.tip.x(), s.tip.y());
    auto depth_inside = [&](uint32_t t) {
        const auto& tr = s.membrane.triangles[t];
        auto p2 = [&](uint32_t v) { return Eigen::Vector2f(s.membrane.vertices_mm[v].x(), s.membrane.vertices_mm[v].y()); };
        return cut - distance_to_triangle_2d(c2, p2(tr[0]), p2(tr[1]), p2(tr[2]));
    };
    for (uint32_t t : exact)
        if (!std::binary_search(got.begin(), got.end(), t)) CHECK(depth_inside(t) < 2.0f * px);
    for (uint32_t t : got)
        if (!std::binary_search(exact.begin(), exact.end(), t)) CHECK(depth_inside(t) > -2.0f * px);
    CHECK(double(common) / double(exact.size()) >= 0.97);
    CHECK(double(common) / double(got.size()) >= 0.99);
    CHECK(r.pi_convex);  // the top-left rule never counts a shared edge twice
}

TEST_CASE("Fig. 7 teapot: non-convex body, deformation equals a ray-cast reference; sets match exact",
          "[sim][collision][zcoll]") {
    PlaneScene s;
    s.tip = Vec3f(0.05f, -0.02f, -0.35f);
    s.membrane = make_membrane_patch(5.0f, 5.0f, 48, 48);
    s.membrane.build_adjacency();
    PosedInstrument pot(teapot_body());
    pot.set_state(0.0f, s.pose());
    ZcollConfig cfg;
    cfg.resolution_px = 128;
    ZcollEngine engine(s.membrane, cfg);
    const ZcollView view = make_tip_view(s.pose(), 2.0f, 0.5f, 2.0f, 128);
    const ZcollResult& r = engine.push(s.membrane.vertices_mm, pot, view);
    REQUIRE(r.colliding);
    CHECK(r.pi_convex);
    const auto v_eye = posed_vertices(pot);
    size_t agree = 0;
    bool handle_hit = false;
    for (const ZcollFeature& f : r.features) {
        const Vec3f o = pixel_on_camera_plane(view, f.x_px, f.y_px);
        const float zi = ray_cast(o, view.direction_eye(), pot.instrument(), v_eye);
        const float zm = -o.z();  // the camera looks along +z at the plane z = 0
        agree += std::fabs((zi - zm) - f.depth_delta_mm) < 2e-3f;
        handle_hit |= o.x() < -0.9f;  // the handle's lowest arc also pierces the membrane
    }
    CHECK(double(agree) >= 0.99 * double(r.features.size()));
    CHECK(handle_hit);
    const auto exact = brute_force_colliding(s.membrane.vertices_mm, s.membrane.triangles, pot.instrument(),
                                             pot.vertices_local_mm(), s.pose());
    const std::vector<uint32_t> got(r.colliding_triangles.begin(), r.colliding_triangles.end());
    const size_t common = intersection_size(got, exact);
    INFO("zcoll " << got.size() << " exact " << exact.size() << " common " << common);
    CHECK(double(common) / double(exact.size()) >= 0.95);
    CHECK(double(common) / double(got.size()) >= 0.98);
}

TEST_CASE("a folded membrane is detected as not π-convex and the fallback returns the exact set",
          "[sim][collision][zcoll]") {
    // Fold the part x > 0.5 back under the sheet (rotation by 170° about the line x = 0.5, z = 0).
    TriangleMesh m = make_membrane_patch(4.0f, 4.0f, 39, 39);
    const float phi = 170.0f * kPi / 180.0f;
    for (Vec3f& v : m.vertices_mm)
        if (v.x() > 0.5f) {
            const float dx = v.x() - 0.5f;
            v = Vec3f(0.5f + dx * std::cos(phi), v.y(), -dx * std::sin(phi));
        }
    PosedInstrument sphere(sphere_body(0.6f));
    const Eigen::Isometry3f pose = pose_at(Vec3f(-0.3f, 0.05f, -0.3f), Vec3f(0, 0, -1));
    sphere.set_state(0.0f, pose);
    ZcollConfig cfg;
    cfg.resolution_px = 32;
    ZcollEngine engine(m, cfg);
    const ZcollView view = make_tip_view(pose, 1.2f, 0.5f, 2.5f, 32);
    const ZcollResult& r = engine.push(m.vertices_mm, sphere, view);
    CHECK_FALSE(r.pi_convex);
    CHECK(r.multi_layer_pixels > 100);
    CHECK(r.fallback_used);
    const auto exact = brute_force_colliding(m.vertices_mm, m.triangles, sphere.instrument(),
                                             sphere.vertices_local_mm(), pose);
    REQUIRE(exact.size() > 20);
    const std::vector<uint32_t> got(r.colliding_triangles.begin(), r.colliding_triangles.end());
    CHECK(got == exact);
    // Without the fallback ZCOLL only sees the front layer (the flap): it misses the layer behind.
    ZcollConfig plain = cfg;
    plain.exact_fallback = false;
    ZcollEngine no_fallback(m, plain);
    const ZcollResult& p = no_fallback.push(m.vertices_mm, sphere, view);
    CHECK_FALSE(p.pi_convex);
    CHECK_FALSE(p.fallback_used);
    CHECK(p.colliding_triangles.size() < exact.size());
}

TEST_CASE("broad-phase gating skips far configurations and never hides a collision", "[sim][collision][zcoll]") {
    PlaneScene s;
    PosedInstrument sphere(sphere_body(0.5f, 24, 32));
    ZcollConfig cfg;
    ZcollEngine engine(s.membrane, cfg);
    const Eigen::Isometry3f far = pose_at(Vec3f(0, 0, -5.0f), Vec3f(0, 0, -1));
    sphere.set_state(0.0f, far);
    const ZcollResult& r = engine.push(s.membrane.vertices_mm, sphere, make_tip_view(far, 1.0f, 0.5f, 2.0f, 32));
    CHECK(r.gated_out);
    CHECK_FALSE(r.colliding);
    CHECK_FALSE(engine.collides(s.membrane.vertices_mm, sphere, make_tip_view(far, 1.0f, 0.5f, 2.0f, 32)));
    std::mt19937 rng(3);
    std::uniform_real_distribution<float> u(-1.0f, 1.0f);
    int gated = 0, colliding = 0;
    for (int i = 0; i < 200; ++i) {
        const Vec3f tip(1.5f * u(rng), 1.5f * u(rng), 1.5f * u(rng));
        const Eigen::Isometry3f pose = pose_at(tip, Vec3f(0.3f * u(rng), 0.3f * u(rng), -1.0f).normalized());
        sphere.set_state(0.0f, pose);
        const ZcollView view = make_tip_view(pose, 1.0f, 0.5f, 2.0f, 32);
        const ZcollResult& q = engine.push(s.membrane.vertices_mm, sphere, view);
        const auto exact = brute_force_colliding(s.membrane.vertices_mm, s.membrane.triangles, sphere.instrument(),
                                                 sphere.vertices_local_mm(), pose);
        gated += q.gated_out;
        colliding += !exact.empty();
        if (q.gated_out) CHECK(exact.empty());
    }
    CHECK(gated > 20);
    CHECK(colliding > 20);
}

TEST_CASE("boolean mode agrees with push mode and allocates nothing", "[sim][collision][zcoll]") {
    PlaneScene s;
    PosedInstrument sphere(sphere_body(0.5f, 24, 32));
    ZcollEngine engine(s.membrane, ZcollConfig{});
    std::mt19937 rng(11);
    std::uniform_real_distribution<float> u(-1.0f, 1.0f);
    int hits = 0;
    long allocations = 0;
    for (int i = 0; i < 300; ++i) {
        const Vec3f tip(u(rng), u(rng), 0.4f * u(rng));
        const Eigen::Isometry3f pose = pose_at(tip, Vec3f(0.2f * u(rng), 0.2f * u(rng), -1.0f).normalized());
        sphere.set_state(0.0f, pose);
        const ZcollView view = make_tip_view(pose, 0.8f, 0.4f, 1.5f, 32);
        const long before = allocation_count();
        const bool b = engine.collides(s.membrane.vertices_mm, sphere, view);
        const bool p = engine.push(s.membrane.vertices_mm, sphere, view).colliding;
        if (i > 0) allocations += allocation_count() - before;
        CHECK(b == p);
        hits += b;
    }
    CHECK(hits > 50);
    CHECK(hits < 250);
    CHECK(allocations == 0);
}

TEST_CASE("per-vertex colour ids name a corner of the triangle seen at the same pixel", "[sim][collision][zcoll]") {
    PlaneScene s;
    PosedInstrument sphere(sphere_body(kSphereR));
    sphere.set_state(0.0f, s.pose());
    ZcollConfig tri_cfg;
    tri_cfg.resolution_px = 64;
    ZcollConfig vtx_cfg = tri_cfg;
    vtx_cfg.features = FeatureKind::Vertex;
    ZcollEngine by_tri(s.membrane, tri_cfg), by_vtx(s.membrane, vtx_cfg);
    const ZcollView view = make_tip_view(s.pose(), 1.2f, 0.5f, 2.5f, 64);
    by_tri.push(s.membrane.vertices_mm, sphere, view);
    const ZcollResult& rv = by_vtx.push(s.membrane.vertices_mm, sphere, view);
    const auto& bt = by_tri.buffers();
    const auto& bv = by_vtx.buffers();
    size_t seen = 0;
    for (size_t p = 0; p < bt.cm.size(); ++p) {
        if (bt.cm[p] == 0) {
            CHECK(bv.cm[p] == 0);
            continue;
        }
        ++seen;
        const auto& tri = s.membrane.triangles[bt.cm[p] - 1];
        const uint32_t v = bv.cm[p] - 1;
        CHECK((v == tri[0] || v == tri[1] || v == tri[2]));
    }
    CHECK(seen > 1000);
    // Vertex mode pushes exactly the vertices seen in colliding pixels, each along −z.
    REQUIRE_FALSE(rv.pushed_nodes.empty());
    for (const Vec3f& v : rv.node_push_eye_mm) CHECK(v.normalized().z() == Approx(-1.0f).margin(1e-5));
}

TEST_CASE("forceps: open jaws push, jaws closed below the threshold grab nodes", "[sim][collision][zcoll]") {
    TriangleMesh m = make_membrane_patch(6.0f, 6.0f, kPatch3k.nx, kPatch3k.ny);
    PosedInstrument forceps(make_forceps());
    const Eigen::Isometry3f pose = pose_at(Vec3f(0.02f, 0.03f, -0.15f), Vec3f(0, 0, -1));
    ZcollConfig cfg;
    cfg.grab_below_deg = 8.0f;
    cfg.grab_radius_mm = 0.2f;
    ZcollEngine engine(m, cfg);
    const ZcollView view = make_tip_view(pose, 1.0f, 0.4f, 1.6f, 32);
    forceps.set_state(30.0f, pose);
    const ZcollResult& open = engine.push(m.vertices_mm, forceps, view);
    CHECK(open.colliding);
    CHECK_FALSE(open.grabbed);
    CHECK_FALSE(open.pushed_nodes.empty());
    CHECK(open.grabbed_nodes.empty());
    forceps.set_state(4.0f, pose);
    const ZcollResult& closed = engine.push(m.vertices_mm, forceps, view);
    REQUIRE(closed.grabbed);
    CHECK(closed.pushed_nodes.empty());
    // Every node of a colliding triangle and every node within the grab radius of the tip is bound.
    std::vector<uint32_t> expect;
    for (uint32_t t : closed.colliding_triangles)
        for (uint32_t v : m.triangles[t]) expect.push_back(v);
    for (uint32_t v = 0; v < m.vertex_count(); ++v)
        if ((m.vertices_mm[v] - forceps.tip_eye_mm()).norm() <= 0.2f) expect.push_back(v);
    std::sort(expect.begin(), expect.end());
    expect.erase(std::unique(expect.begin(), expect.end()), expect.end());
    CHECK(std::vector<uint32_t>(closed.grabbed_nodes.begin(), closed.grabbed_nodes.end()) == expect);
}

TEST_CASE("vitrector suction: nodes in the cone get forces ∝ 1/distance towards the port", "[sim][collision][zcoll]") {
    TriangleMesh m = make_membrane_patch(6.0f, 6.0f, kPatch3k.nx, kPatch3k.ny);
    // The vitrector lies 0.6 mm above the membrane (z = 0) with its side opening facing down.
    PosedInstrument vit(make_vitrector());
    Eigen::Isometry3f pose = Eigen::Isometry3f::Identity();
    pose.linear().col(0) = Vec3f(0, 0, -1);  // port normal (+x of the instrument) → −z of the eye
    pose.linear().col(1) = Vec3f(0, 1, 0);
    pose.linear().col(2) = Vec3f(1, 0, 0);
    pose.translation() = Vec3f(0.5f, 0.1f, 0.6f + 0.18f);
    vit.set_state(0.0f, pose);
    ZcollConfig cfg;
    cfg.resolution_px = 64;
    cfg.suction_gain_mm2 = 0.02f;
    ZcollEngine engine(m, cfg);
    const ZcollView cone = make_suction_view(pose, vit.instrument(), 30.0f, 2.0f, 64);
    const Vec3f port = pose * vit.instrument().port_local_mm;
    CHECK(port.z() == Approx(0.6f).margin(1e-5));
    const ZcollResult& r = engine.suction(m.vertices_mm, cone, port);
    REQUIRE(r.colliding);
    REQUIRE(r.suction_nodes.size() == r.suction_force_eye.size());
    const float tan30 = std::tan(30.0f * kPi / 180.0f);
    size_t strictly_inside = 0;
    for (uint32_t v = 0; v < m.vertex_count(); ++v) {
        const Vec3f c = cone.to_camera(m.vertices_mm[v]);
        const bool in = c.z() > 0 && std::fabs(c.x()) < 0.9f * c.z() * tan30 && std::fabs(c.y()) < 0.9f * c.z() * tan30;
        strictly_inside += in;
        if (in) CHECK(std::binary_search(r.suction_nodes.begin(), r.suction_nodes.end(), v));
    }
    CHECK(strictly_inside > 10);  // the cone meets the membrane 0.6 mm from the port: ≈ 0.7 mm wide
    for (size_t k = 0; k < r.suction_nodes.size(); ++k) {
        const Vec3f to_port = port - m.vertices_mm[r.suction_nodes[k]];
        const Vec3f f = r.suction_force_eye[k];
        CHECK(f.norm() == Approx(0.02f / to_port.norm()).epsilon(1e-4));
        CHECK(f.normalized().dot(to_port.normalized()) == Approx(1.0f).margin(1e-5));
        const Vec3f c = cone.to_camera(m.vertices_mm[r.suction_nodes[k]]);
        CHECK(std::fabs(c.x()) <= c.z() * tan30 + 1e-5f);
    }
}

TEST_CASE("ZCOLL queries on a membrane deforming every frame allocate nothing", "[sim][collision][zcoll]") {
    PlaneScene s;
    std::vector<Vec3f> verts = s.membrane.vertices_mm;
    PosedInstrument forceps(make_forceps());
    ZcollEngine engine(s.membrane, ZcollConfig{});
    const Eigen::Isometry3f pose = pose_at(Vec3f(0, 0, -0.2f), Vec3f(0, 0, -1));
    const ZcollView view = make_tip_view(pose, 1.0f, 0.4f, 1.6f, 32);
    forceps.set_state(20.0f, pose);
    engine.push(verts, forceps, view);  // warm-up
    long allocations = 0;
    size_t collided = 0;
    for (int frame = 0; frame < 50; ++frame) {
        for (Vec3f& v : verts) v.z() = 0.05f * std::sin(0.3f * float(frame) + 2.0f * v.x());
        forceps.set_state(20.0f + float(frame % 5), pose);
        const long before = allocation_count();
        collided += engine.push(verts, forceps, view).colliding_triangles.size();
        allocations += allocation_count() - before;
    }
    CHECK(collided > 0);
    CHECK(allocations == 0);
}

TEST_CASE("exact narrow phase: grid + flood-filled containment equals brute force", "[sim][collision][zcoll]") {
    // A deep push: many membrane triangles lie entirely inside the sphere.
    TriangleMesh m = make_membrane_patch(4.0f, 4.0f, 39, 39);
    PosedInstrument sphere(sphere_body(0.8f, 32, 48));
    ExactNarrowPhase exact(m.triangle_count(), sphere.instrument().mesh.triangle_count());
    std::mt19937 rng(9);
    std::uniform_real_distribution<float> u(-1.0f, 1.0f);
    size_t contained_cases = 0;
    for (int i = 0; i < 6; ++i) {
        const Eigen::Isometry3f pose = pose_at(Vec3f(0.5f * u(rng), 0.5f * u(rng), -0.3f - 0.6f * std::fabs(u(rng))),
                                               Vec3f(0.3f * u(rng), 0.3f * u(rng), -1.0f).normalized());
        sphere.set_state(0.0f, pose);
        const auto truth = brute_force_colliding(m.vertices_mm, m.triangles, sphere.instrument(),
                                                 sphere.vertices_local_mm(), pose);
        const MeshRef mem{m.vertices_mm, m.triangles, Eigen::Isometry3f::Identity()};
        const MeshRef ins{sphere.vertices_local_mm(), sphere.instrument().mesh.triangles, pose};
        ExactOptions plain;
        const auto a = exact.colliding_triangles(mem, ins, sphere.instrument().part_triangle_begin, plain);
        CHECK(std::vector<uint32_t>(a.begin(), a.end()) == truth);
        const size_t surface_only = [&] {
            ExactOptions o;
            o.include_contained = false;
            return exact.colliding_triangles(mem, ins, sphere.instrument().part_triangle_begin, o).size();
        }();
        contained_cases += surface_only < truth.size();
        ExactOptions flood;
        flood.vertex_triangle_begin = m.vertex_triangle_begin;
        flood.vertex_triangles = m.vertex_triangles;
        const auto b = exact.colliding_triangles(mem, ins, sphere.instrument().part_triangle_begin, flood);
        CHECK(std::vector<uint32_t>(b.begin(), b.end()) == truth);
    }
    CHECK(contained_cases >= 4);  // the scenes exercise containment, not only surface hits
}

TEST_CASE("pick touching the curved retina: ZCOLL on the hemisphere, eye-wall warning", "[sim][collision][zcoll]") {
    const TriangleMesh retina = make_retina_hemisphere(kEyeRadius_mm - 0.5f, 40, 128);
    PosedInstrument pick(make_pick());
    // Tip 0.15 mm beyond the inner wall near the posterior pole, pointing outwards along −z (slightly tilted).
    const Vec3f dir = Vec3f(0.1f, -0.05f, -1.0f).normalized();
    const Eigen::Isometry3f pose = pose_at(dir * (kEyeRadius_mm - 0.5f + 0.15f), dir);
    pick.set_state(0.0f, pose);
    ZcollConfig cfg;
    cfg.resolution_px = 128;
    ZcollEngine engine(retina, cfg);
    // π along the local wall normal (outwards at the tip), camera outside the wall looking back in.
    const ZcollView view = make_tip_view_along(pick.tip_eye_mm(), -dir, Vec3f(0, 1, 0), 0.6f, 0.4f, 1.0f, 128);
    const ZcollResult& r = engine.push(retina.vertices_mm, pick, view);
    REQUIRE(r.colliding);
    CHECK(r.pi_convex);  // a small V on a 11.5 mm sphere is a height field
    const auto exact = brute_force_colliding(retina.vertices_mm, retina.triangles, pick.instrument(),
                                             pick.vertices_local_mm(), pose);
    REQUIRE_FALSE(exact.empty());
    const std::vector<uint32_t> got(r.colliding_triangles.begin(), r.colliding_triangles.end());
    const size_t common = intersection_size(got, exact);
    INFO("zcoll " << got.size() << " exact " << exact.size() << " common " << common);
    CHECK(double(common) >= 0.8 * double(exact.size()));
    // Push vectors point inwards-to-outwards along the wall normal (towards the camera side = outside).
    for (const Vec3f& v : r.node_push_eye_mm) CHECK(v.normalized().dot(dir) == Approx(1.0f).margin(1e-4));
    for (const Vec3f& v : r.node_push_eye_mm) CHECK(v.norm() <= 0.15f + 0.02f);
    // Case 2 on the same tip: beyond the wall, warning on.
    EyeSphereMonitor wall({kEyeRadius_mm - 0.5f, 0.5f, 0.6f});
    const EyeSphereContact c = wall.update(pick.tip_eye_mm());
    CHECK(c.distance_mm == Approx(-0.15f).margin(1e-4));
    CHECK(c.warning);
    CHECK(c.warning_started);
}

TEST_CASE("a reused engine gives exactly what a fresh engine gives (no stale pixels)", "[sim][collision][zcoll]") {
    PlaneScene s;
    PosedInstrument sphere(sphere_body(0.5f, 24, 32));
    ZcollConfig cfg;
    cfg.resolution_px = 48;
    ZcollEngine reused(s.membrane, cfg);
    std::mt19937 rng(21);
    std::uniform_real_distribution<float> u(-1.0f, 1.0f);
    for (int i = 0; i < 40; ++i) {
        const Eigen::Isometry3f pose = pose_at(Vec3f(1.5f * u(rng), 1.5f * u(rng), 0.4f * u(rng)),
                                               Vec3f(0.3f * u(rng), 0.3f * u(rng), -1.0f).normalized());
        sphere.set_state(0.0f, pose);
        const ZcollView view = make_tip_view(pose, 0.3f + 0.5f * std::fabs(u(rng)), 0.4f, 1.5f, 48);
        ZcollEngine fresh(s.membrane, cfg);
        const ZcollResult& a = reused.push(s.membrane.vertices_mm, sphere, view);
        const ZcollResult& b = fresh.push(s.membrane.vertices_mm, sphere, view);
        CHECK(std::vector<uint32_t>(a.colliding_triangles.begin(), a.colliding_triangles.end()) ==
              std::vector<uint32_t>(b.colliding_triangles.begin(), b.colliding_triangles.end()));
        CHECK(a.features.size() == b.features.size());
        CHECK(reused.buffers().cm == fresh.buffers().cm);
        CHECK(reused.buffers().zm_mm == fresh.buffers().zm_mm);
        CHECK(reused.buffers().zi_mm == fresh.buffers().zi_mm);
        CHECK(reused.buffers().layers == fresh.buffers().layers);
    }
}

TEST_CASE("stress: random deforming membranes and forceps poses stay consistent", "[sim][collision][zcoll][stress]") {
    TriangleMesh base = make_membrane_patch(4.0f, 4.0f, kPatch3k.nx, kPatch3k.ny);
    std::vector<Vec3f> verts = base.vertices_mm;
    PosedInstrument forceps(make_forceps());
    ZcollEngine engine(base, ZcollConfig{});
    std::mt19937 rng(77);
    std::uniform_real_distribution<float> u(-1.0f, 1.0f);
    int fallbacks = 0, hits = 0;
    for (int i = 0; i < 20000; ++i) {
        // A wave, sometimes steep enough to fold over itself inside V.
        const float amp = 0.3f * std::fabs(u(rng)), k = 3.0f + 4.0f * std::fabs(u(rng)), ph = 3.0f * u(rng);
        for (size_t v = 0; v < verts.size(); ++v) {
            const Vec3f& p = base.vertices_mm[v];
            verts[v] = Vec3f(p.x() + amp * std::sin(k * p.y() + ph), p.y(), amp * std::cos(k * p.x() + ph));
        }
        const Eigen::Isometry3f pose = pose_at(Vec3f(u(rng), u(rng), 0.5f * u(rng)),
                                               Vec3f(0.5f * u(rng), 0.5f * u(rng), -1.0f).normalized());
        forceps.set_state(40.0f * std::fabs(u(rng)), pose);
        const ZcollView view = make_tip_view(pose, 0.8f, 0.4f, 1.6f, 32);
        const ZcollResult& r = engine.push(verts, forceps, view);
        const bool colliding = r.colliding;
        fallbacks += r.fallback_used;
        hits += colliding;
        for (const Vec3f& v : r.node_push_eye_mm) REQUIRE(std::isfinite(v.norm()));
        for (const ZcollFeature& f : r.features) REQUIRE(f.depth_delta_mm <= 0.0f);
        if (r.pi_convex) CHECK(engine.collides(verts, forceps, view) == colliding);
    }
    CHECK(hits > 2000);
    CHECK(fallbacks > 50);
}

TEST_CASE("the engine keeps its own topology and rejects a vertex span of the wrong size", "[sim][collision][zcoll]") {
    PosedInstrument sphere(sphere_body(1.0f));
    const Eigen::Isometry3f pose = pose_at(Vec3f(0.03f, 0.02f, -0.3f), Vec3f(0, 0, -1));
    sphere.set_state(0.0f, pose);
    const ZcollView view = make_tip_view(pose, 1.2f, 0.5f, 2.5f, 32);
    auto membrane = std::make_unique<TriangleMesh>(make_membrane_patch(4.0f, 4.0f, 39, 39));
    const std::vector<Vec3f> verts = membrane->vertices_mm;
    ZcollEngine engine(*membrane, ZcollConfig{});
    membrane.reset();  // the caller's mesh is gone; the engine must not depend on it
    const ZcollResult& r = engine.push(verts, sphere, view);
    CHECK_FALSE(r.invalid_input);
    CHECK(r.colliding);
    const std::vector<Vec3f> short_span(verts.begin(), verts.end() - 1);
    const ZcollResult& bad = engine.push(short_span, sphere, view);
    CHECK(bad.invalid_input);
    CHECK_FALSE(bad.colliding);
    CHECK_FALSE(engine.collides(short_span, sphere, view));
}
