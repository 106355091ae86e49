// Tool interactions: push vectors, suction, lift-off warning, injection and the needle tear warning.
#include "tissue_test_util.hpp"

#include "eyesim/sim/mesh.hpp"

#include <catch2/catch.hpp>

#include <cmath>

using namespace tissue_test;

TEST_CASE("push vectors are added to positions of dynamic nodes only", "[tissue][tools]") {
    Tissue t(patch400(), MaterialParams{}, TissueParams{}, IntegratorKind::kPaperEuler);
    t.fix_rim();
    const Vec3f a = t.system().x_mm[112], rim = t.system().x_mm[0];
    const NodePush pushes[] = {{112, Vec3f(0, 0, 0.25f)}, {0, Vec3f(1, 1, 1)},
                               {112, Vec3f(0, 0, std::nanf(""))}, {99999, Vec3f(1, 0, 0)}};
    t.push(pushes);
    CHECK(t.system().x_mm[112] == a + Vec3f(0, 0, 0.25f));
    CHECK(t.system().x_mm[0] == rim);
}

TEST_CASE("suction pulls nodes inside the cone toward the apex with force ∝ 1/distance", "[tissue][tools]") {
    // Free nodes without springs: after one symplectic step v = F/m · dt exactly.
    const std::vector<Vec3f> x{Vec3f(0, 0, -1.0f), Vec3f(0, 0, -0.5f), Vec3f(0.0f, 1.0f, -0.2f)};
    const std::vector<float> m{2, 2, 2};
    Tissue t(MassSpringSystem::from_springs(x, m, {}), TissueParams{}, IntegratorKind::kSymplecticEuler);
    SuctionInput s;
    s.on = true;
    s.apex_mm = Vec3f::Zero();
    s.axis = Vec3f(0, 0, -1);
    s.half_angle_deg = 30.0f;  // node 2 is at 78.7° off-axis: outside
    s.strength_nN_mm = 3.0f;
    t.set_suction(s);
    const float dt = 1e-3f;
    t.step(dt, 1);
    CHECK(t.system().v_mm_per_s[0].z() == Approx(3.0 / 1.0 / 2.0 * dt).epsilon(1e-5));
    CHECK(t.system().v_mm_per_s[1].z() == Approx(3.0 / 0.5 / 2.0 * dt).epsilon(1e-5));
    CHECK(t.system().v_mm_per_s[2].norm() == 0.0f);
    s.on = false;
    t.set_suction(s);
    const Vec3f v0 = t.system().v_mm_per_s[0];
    t.step(dt, 1);
    CHECK(t.system().v_mm_per_s[0] == v0);  // no force once suction stops
}

TEST_CASE("lift-off warning fires when the force on a rim node exceeds the limit", "[tissue][tools]") {
    // Anchor 0 fixed, node 1 stretched by 0.5 mm: force on the anchor = k·0.5 = 50 nN.
    for (float limit : {49.0f, 51.0f}) {
        TissueParams p;
        p.lift_off_force_nN = limit;
        Tissue t(single_spring(1.0f, 100.0f, 0.0f, 1.0f, 1.5f), p, IntegratorKind::kPaperEuler);
        t.set_node_state(std::vector<uint32_t>{0}, NodeState::kFixed);
        t.step(1e-6f, 1);
        INFO("limit " << limit);
        if (limit < 50.0f) {
            REQUIRE(t.events().count(TissueEventKind::kLiftOff) == 1);
            CHECK(t.events()[0].node == 0);
            CHECK(t.events()[0].value == Approx(50.0).epsilon(1e-5));
        } else {
            CHECK(t.events().count(TissueEventKind::kLiftOff) == 0);
        }
    }
}

TEST_CASE("injection detaches retina nodes within d ∝ p and forms bubbles; attached nodes stay", "[tissue][tools]") {
    const float R = 12.0f;
    const TriangleMesh mesh = make_retina_hemisphere(R, 24, 64);
    CHECK(mesh.triangle_count() == size_t(64 * (2 * 24 - 1)));
    TissueParams p;
    p.container_radius_mm = R;
    p.detach_pressure_min = 0.5f;
    p.detach_radius_mm_per_pressure = 1.5f;
    p.injection_force_nN_per_pressure = 2.0f;
    p.drag_per_s = 50.0f;
    p.tear_warning_speed_mm_per_s = 5.0f;
    MaterialParams mat;
    mat.rest_length_scale = 1.0f;
    Tissue t(mesh, mat, p, IntegratorKind::kImplicitEuler);
    t.attach_all();
    const std::vector<Vec3f> x0 = t.system().x_mm;

    NeedleInput needle;
    needle.inserted = true;
    needle.tip_mm = Vec3f(0, 0, -R - 0.5f);  // beneath the retina (subretinal space), at the posterior pole
    needle.pressure = 0.4f;  // below the minimum: nothing detaches
    t.set_needle(needle);
    t.step(0.01f, 2);
    CHECK(t.damage().nodes_detached == 0);

    needle.pressure = 2.0f;  // d = 3 mm
    needle.velocity_mm_per_s = Vec3f(0, 0, 50.0f);  // along the normal: no tear warning
    t.set_needle(needle);
    t.step(0.01f, 2);
    size_t expect = 0;
    for (const Vec3f& x : x0) expect += (x - needle.tip_mm).norm() <= 3.0f;
    CHECK(t.damage().nodes_detached == expect);
    CHECK(t.events().count(TissueEventKind::kTearWarning) == 0);
    for (uint32_t v = 0; v < x0.size(); ++v) {
        const bool inside = (x0[v] - needle.tip_mm).norm() <= 3.0f;
        CHECK(t.system().state[v] == (inside ? NodeState::kDetached : NodeState::kAttached));
        if (inside && (x0[v] - needle.tip_mm).norm() > 1e-3f) {
            // Constant force of magnitude 2·p along x_i − x0.
            CHECK(t.system().ext_nN[v].norm() == Approx(4.0).epsilon(1e-4));
            CHECK(t.system().ext_nN[v].normalized().dot((x0[v] - needle.tip_mm).normalized()) > 0.9999f);
        }
    }
    // A second injection elsewhere, moving the needle along the retina too fast: tear warning.
    needle.tip_mm = (R + 0.5f) * Vec3f(std::sin(1.0f), 0, -std::cos(1.0f));
    needle.velocity_mm_per_s = Vec3f(0, 8.0f, 0);  // tangential 8 mm/s > 5
    t.set_needle(needle);
    t.step(0.01f, 2);
    REQUIRE(t.events().count(TissueEventKind::kTearWarning) == 1);
    CHECK(t.events()[0].value == Approx(8.0).epsilon(1e-5));
    needle.inserted = false;
    t.set_needle(needle);
    for (int i = 0; i < 300; ++i) t.step(0.01f, 2);
    // Bubbles: detached nodes moved off the choroid (inward), attached ones did not move at all.
    double max_lift = 0;
    for (uint32_t v = 0; v < x0.size(); ++v) {
        const float r = (t.system().x_mm[v] - p.container_centre_mm).norm();
        CHECK(r <= R + 1e-4f);
        if (t.system().state[v] == NodeState::kAttached) REQUIRE(t.system().x_mm[v] == x0[v]);
        else max_lift = std::max(max_lift, double(R - r));
    }
    CHECK(max_lift > 0.05);
    const char* why = "";
    CHECK(t.system().check_consistency(&why));
}

TEST_CASE("constant loads persist through suction switching on and off", "[tissue][tools]") {
    const std::vector<Vec3f> x{Vec3f(0, 0, -1.0f)};
    const std::vector<float> m{2};
    Tissue t(MassSpringSystem::from_springs(x, m, {}), TissueParams{}, IntegratorKind::kSymplecticEuler);
    t.set_constant_force(0, Vec3f(1.0f, 0, 0));
    SuctionInput s;
    s.on = true;
    s.axis = Vec3f(0, 0, -1);
    s.strength_nN_mm = 3.0f;
    t.set_suction(s);
    const float dt = 1e-3f;
    t.step(dt, 1);
    CHECK(t.system().v_mm_per_s[0].x() == Approx(0.5 * dt).epsilon(1e-5));
    CHECK(t.system().v_mm_per_s[0].z() == Approx(1.5 * dt).epsilon(1e-3));
    s.on = false;
    t.set_suction(s);
    const Vec3f v1 = t.system().v_mm_per_s[0];
    t.step(dt, 1);
    CHECK(t.system().v_mm_per_s[0].x() == Approx(v1.x() + 0.5 * dt).epsilon(1e-5));
    CHECK(t.system().v_mm_per_s[0].z() == v1.z());
}
