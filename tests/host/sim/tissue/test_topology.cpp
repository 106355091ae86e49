// Topology changes: tearing and cutting keep springs, triangles and the rendered mesh consistent.
#include "tissue_test_util.hpp"

#include <Eigen/Geometry>
#include <catch2/catch.hpp>

#include <set>

using namespace tissue_test;

namespace {

// Independent check of a mesh written by the tissue: every triangle edge is a live edge spring, no triangle uses a
// removed node, and the mesh adjacency agrees with its triangles.
void check_written_mesh(const Tissue& t, const TriangleMesh& mesh) {
    const MassSpringSystem& s = t.system();
    std::set<std::pair<uint32_t, uint32_t>> springs;
    for (const Spring& sp : s.springs) springs.insert({std::min(sp.a, sp.b), std::max(sp.a, sp.b)});
    REQUIRE(mesh.triangle_count() == s.live_triangle_count());
    REQUIRE(mesh.vertex_count() == s.node_count());
    for (const auto& tri : mesh.triangles)
        for (int k = 0; k < 3; ++k) {
            REQUIRE(s.state[tri[k]] != NodeState::kRemoved);
            const uint32_t a = tri[k], b = tri[(k + 1) % 3];
            REQUIRE(springs.count({std::min(a, b), std::max(a, b)}) == 1);
        }
    REQUIRE(mesh.vertex_triangle_begin.size() == mesh.vertex_count() + 1);
    REQUIRE(mesh.vertex_triangle_begin.back() == 3 * mesh.triangle_count());
}

}  // namespace

TEST_CASE("cutting removes exactly the triangles touching the cutter's reach", "[tissue][topology]") {
    const TriangleMesh mesh = patch400();
    Tissue t(mesh, MaterialParams{}, TissueParams{}, IntegratorKind::kPaperEuler);
    t.fix_rim();
    CutterInput cut;
    cut.on = true;
    cut.centre_mm = Vec3f(0.3f, -0.2f, 0.0f);
    cut.radius_mm = 0.7f;
    t.set_cutter(cut);
    t.step(1e-3f, 1);
    // Brute force on the original mesh: triangles with a vertex within the reach.
    double area = 0;
    size_t tris = 0;
    std::set<uint32_t> cut_nodes;
    for (uint32_t v = 0; v < mesh.vertex_count(); ++v)
        if ((mesh.vertices_mm[v] - cut.centre_mm).norm() <= cut.radius_mm) cut_nodes.insert(v);
    for (const auto& tri : mesh.triangles) {
        if (!cut_nodes.count(tri[0]) && !cut_nodes.count(tri[1]) && !cut_nodes.count(tri[2])) continue;
        ++tris;
        area += 0.5 * (mesh.vertices_mm[tri[1]] - mesh.vertices_mm[tri[0]])
                          .cross(mesh.vertices_mm[tri[2]] - mesh.vertices_mm[tri[0]])
                          .norm();
    }
    REQUIRE(tris > 0);
    CHECK(t.damage().triangles_cut == tris);
    CHECK(t.damage().removed_area_mm2 == Approx(area).epsilon(1e-5));
    CHECK(t.damage().nodes_cut == cut_nodes.size());  // a disc cut leaves no orphan nodes
    REQUIRE(t.events().count(TissueEventKind::kTissueRemoved) == 1);
    const char* why = "";
    CHECK(t.system().check_consistency(&why));
    INFO(why);
    TriangleMesh out;
    CHECK(t.write_to(out));
    check_written_mesh(t, out);
    CHECK_FALSE(t.write_to(out));  // no topology change since: positions only
}

TEST_CASE("tearing under a pulling forceps keeps the mesh consistent", "[tissue][topology]") {
    for (IntegratorKind kind : kAllIntegrators) {
        INFO(to_string(kind));
        TissueParams p;
        p.a_max_mm_per_s2 = 2e5f;
        p.p_tear_percent = 20.0f;
        p.v_max_mm_per_s = 500.0f;
        p.drag_per_s = 20.0f;
        MaterialParams mat;
        mat.bending_stiffness_nN_per_mm = 100.0f;
        Tissue t(patch400(), mat, p, kind);
        t.fix_rim();
        ForcepsInput f;
        f.tip_mm = Vec3f(0, 0, 0);
        f.grab_radius_mm = 0.3f;
        f.closed = true;
        t.set_forceps(f);
        TriangleMesh out;
        for (int frame = 0; frame < 200; ++frame) {
            f.tip_mm = Vec3f(0.0f, 0.02f * float(frame), 0.01f * float(frame));  // pull up and sideways
            t.set_forceps(f);
            t.step(1e-3f, 2);
            const char* why = "";
            REQUIRE(t.system().check_consistency(&why));
            t.write_to(out);
        }
        CHECK(t.damage().springs_torn > 0);
        CHECK(t.damage().triangles_torn > 0);
        check_written_mesh(t, out);
    }
}

TEST_CASE("grabbed nodes follow the tip exactly and are released on opening", "[tissue][tools]") {
    Tissue t(patch400(), MaterialParams{}, TissueParams{}, IntegratorKind::kPaperEuler);
    t.fix_rim();
    ForcepsInput f;
    f.tip_mm = Vec3f(0.05f, 0.05f, 0);
    f.grab_radius_mm = 0.2f;
    f.closed = true;
    t.set_forceps(f);
    std::vector<uint32_t> inside;
    for (uint32_t v = 0; v < t.system().node_count(); ++v)
        if ((t.system().x_mm[v] - f.tip_mm).norm() <= f.grab_radius_mm) inside.push_back(v);
    REQUIRE(!inside.empty());
    std::vector<Vec3f> offset;
    for (uint32_t v : inside) offset.push_back(t.system().x_mm[v] - f.tip_mm);
    f.tip_mm += Vec3f(0, 0, 0.4f);
    t.set_forceps(f);
    t.step(0.01f, 5);
    for (size_t k = 0; k < inside.size(); ++k) {
        CHECK(t.system().state[inside[k]] == NodeState::kGrabbed);
        CHECK((t.system().x_mm[inside[k]] - (f.tip_mm + offset[k])).norm() < 1e-6f);
    }
    f.closed = false;
    t.set_forceps(f);
    for (uint32_t v : inside) CHECK(t.system().state[v] == NodeState::kFree);
}
