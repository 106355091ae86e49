// Collision benchmark (paper Tables 1–2): ZCOLL on the CPU and through EGL/GLES3 against FCL and Bullet, run
// time beside recall/precision of the colliding membrane triangles against the exact set, in the same run.
//
// Usage: bench_collision [--repeats N] [--quick]
//   Prints a Markdown table (median and p90 of N timed queries per method) and the scene set-up.

#include "eyesim/render/zcoll_gles.hpp"
#include "eyesim/sim/collision/exact.hpp"
#include "eyesim/sim/collision/instrument.hpp"
#include "eyesim/sim/collision/tri_tri.hpp"
#include "eyesim/sim/collision/zcoll.hpp"

#include <BulletCollision/CollisionShapes/btTriangleIndexVertexArray.h>
#include <BulletCollision/Gimpact/btGImpactShape.h>
#include <fcl/geometry/bvh/BVH_model.h>
#include <fcl/narrowphase/collision.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <ctime>
#include <functional>
#include <memory>
#include <string>
#include <vector>

using namespace eyesim::sim;
using namespace eyesim::sim::collision;

namespace {

using Clock = std::chrono::steady_clock;
constexpr float kPi = 3.14159265358979f;

struct Timing {
    double median_us = 0, p90_us = 0;  ///< wall clock
    double cpu_median_us = 0;          ///< CPU time of the calling thread (robust against a busy machine)
};

double thread_cpu_us() {
    timespec ts{};
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
    return double(ts.tv_sec) * 1e6 + double(ts.tv_nsec) * 1e-3;
}

/// Times `fn(i)` `repeats` times (after 3 warm-up calls); `prepare(i)` runs untimed before each call.
Timing time_it(int repeats, const std::function<void(int)>& prepare, const std::function<void(int)>& fn) {
    std::vector<double> t, c;
    t.reserve(size_t(repeats));
    c.reserve(size_t(repeats));
    for (int i = -3; i < repeats; ++i) {
        prepare(i);
        const double c0 = thread_cpu_us();
        const auto t0 = Clock::now();
        fn(i);
        const auto t1 = Clock::now();
        const double c1 = thread_cpu_us();
        if (i >= 0) {
            t.push_back(std::chrono::duration<double, std::micro>(t1 - t0).count());
            c.push_back(c1 - c0);
        }
    }
    std::sort(t.begin(), t.end());
    std::sort(c.begin(), c.end());
    return {t[t.size() / 2], t[std::min(t.size() - 1, t.size() * 9 / 10)], c[c.size() / 2]};
}

struct Quality {
    size_t found = 0;
    double recall = 0, precision = 0;
};

Quality quality(std::vector<uint32_t> got, const std::vector<uint32_t>& exact) {
    std::sort(got.begin(), got.end());
    got.erase(std::unique(got.begin(), got.end()), got.end());
    size_t common = 0;
    for (uint32_t t : got) common += std::binary_search(exact.begin(), exact.end(), t);
    Quality q;
    q.found = got.size();
    q.recall = exact.empty() ? 1.0 : double(common) / double(exact.size());
    q.precision = got.empty() ? 1.0 : double(common) / double(got.size());
    return q;
}

Eigen::Isometry3f pose_at(const Vec3f& tip, const Vec3f& forward) {
    const Vec3f z = forward.normalized();
    const Vec3f y = z.cross(std::fabs(z.x()) < 0.9f ? Vec3f::UnitX() : Vec3f::UnitY()).normalized();
    Eigen::Isometry3f t = Eigen::Isometry3f::Identity();
    t.linear().col(0) = y.cross(z);
    t.linear().col(1) = y;
    t.linear().col(2) = z;
    t.translation() = tip;
    return t;
}

struct Scene {
    std::string name;
    TriangleMesh membrane;
    float tilt_deg = 0, depth_mm = 0, opening_deg = 30;
    float half_width_mm = 1.0f, ahead_mm = 0.5f, behind_mm = 2.0f;
    Eigen::Isometry3f pose = Eigen::Isometry3f::Identity();
    std::vector<uint32_t> exact;
};

Eigen::Isometry3f scene_pose(float tilt_deg, float depth_mm) {
    const float a = tilt_deg * kPi / 180.0f;
    return pose_at(Vec3f(0.11f, 0.07f, -depth_mm), Vec3f(std::sin(a), 0.0f, -std::cos(a)));
}

/// Exact colliding membrane triangles (surface intersections and triangles inside the instrument).
std::vector<uint32_t> exact_set(const TriangleMesh& membrane, const PosedInstrument& ins) {
    ExactNarrowPhase exact(membrane.triangle_count(), ins.instrument().mesh.triangle_count());
    const MeshRef m{membrane.vertices_mm, membrane.triangles, Eigen::Isometry3f::Identity()};
    const MeshRef t{ins.vertices_local_mm(), ins.instrument().mesh.triangles, ins.instrument_to_eye()};
    ExactOptions opt;
    opt.vertex_triangle_begin = membrane.vertex_triangle_begin;
    opt.vertex_triangles = membrane.vertex_triangles;
    const auto s = exact.colliding_triangles(m, t, ins.instrument().part_triangle_begin, opt);
    return {s.begin(), s.end()};
}

/// Pose search: the smallest approach angle (from the membrane normal) at which some push depth (≤ 1.5 mm,
/// 0.02 mm steps) reaches `target` exactly colliding triangles; then the depth by bisection below that step.
/// V is fitted around the tip to hold every exactly colliding triangle (π = membrane normal).
void calibrate(Scene& s, PosedInstrument& forceps, size_t target) {
    float found_depth = -1.0f;
    for (float tilt : {0.0f, 15.0f, 30.0f, 45.0f, 60.0f, 70.0f, 75.0f, 80.0f, 85.0f}) {
        s.tilt_deg = tilt;
        for (float d = 0.02f; d <= 1.5f && found_depth < 0; d += 0.02f) {
            forceps.set_state(s.opening_deg, scene_pose(tilt, d));
            if (exact_set(s.membrane, forceps).size() >= target) found_depth = d;
        }
        if (found_depth >= 0) break;
    }
    if (found_depth < 0) found_depth = 1.5f;
    float lo = std::max(0.0f, found_depth - 0.02f), hi = found_depth;
    for (int it = 0; it < 20; ++it) {
        const float mid = 0.5f * (lo + hi);
        forceps.set_state(s.opening_deg, scene_pose(s.tilt_deg, mid));
        (exact_set(s.membrane, forceps).size() < target ? lo : hi) = mid;
    }
    s.depth_mm = hi;
    s.pose = scene_pose(s.tilt_deg, hi);
    forceps.set_state(s.opening_deg, s.pose);
    s.exact = exact_set(s.membrane, forceps);
    float reach = 0.3f;
    const Vec3f tip = s.pose.translation();
    for (uint32_t t : s.exact)
        for (uint32_t v : s.membrane.triangles[t])
            reach = std::max({reach, std::fabs(s.membrane.vertices_mm[v].x() - tip.x()),
                              std::fabs(s.membrane.vertices_mm[v].y() - tip.y())});
    s.half_width_mm = std::ceil((reach + 0.05f) * 4.0f) / 4.0f;
    s.ahead_mm = 0.5f;                 // camera 0.5 mm beyond the tip (below the membrane)
    s.behind_mm = s.depth_mm + 0.5f;   // V reaches 0.5 mm above the undeformed membrane
}

ZcollView scene_view(const Scene& s, int r) {
    return make_tip_view_along(s.pose.translation(), Vec3f(0, 0, 1), Vec3f(0, 1, 0), s.half_width_mm, s.ahead_mm,
                               s.behind_mm, r);
}

struct Row {
    std::string scene, method;
    int r = 0;
    Timing t;
    Quality q;
};

/// One table row. Speed-up against FCL refit: thread CPU time for CPU methods, wall time for EGL (llvmpipe
/// rasterises on worker threads the calling thread's CPU clock does not see).
void print_row(const Row& row, const Timing& fcl_refit) {
    const bool egl = row.method.find("EGL") != std::string::npos;
    const double ratio = egl ? fcl_refit.median_us / row.t.median_us : fcl_refit.cpu_median_us / row.t.cpu_median_us;
    std::printf("| %s | %s | %s | %.1f | %.1f | %s | %.1f%s | %zu | %.3f | %.3f |\n", row.scene.c_str(),
                row.method.c_str(), row.r ? std::to_string(row.r).c_str() : "–", row.t.median_us, row.t.p90_us,
                egl ? "–" : (std::to_string(int(row.t.cpu_median_us * 10 + 0.5) / 10) + "." +
                             std::to_string(int(row.t.cpu_median_us * 10 + 0.5) % 10)).c_str(),
                ratio, egl ? " (wall)" : "", row.q.found, row.q.recall, row.q.precision);
    std::fflush(stdout);
}

}  // namespace

int main(int argc, char** argv) {
    int repeats = 200;
    bool quick = false;
    for (int i = 1; i < argc; ++i) {
        if (!std::strcmp(argv[i], "--repeats") && i + 1 < argc) repeats = std::max(5, std::atoi(argv[++i]));
        else if (!std::strcmp(argv[i], "--quick")) quick = true;
        else {
            std::fprintf(stderr, "usage: %s [--repeats N] [--quick]\n", argv[0]);
            return 2;
        }
    }
    if (quick) repeats = std::min(repeats, 20);

    PosedInstrument forceps(make_forceps());
    std::string egl_error;
    auto egl_probe = eyesim::render::GlesZcollBackend::create(egl_error);
    const std::string renderer = egl_probe ? egl_probe->context().renderer() : std::string("unavailable: ") + egl_error;
    egl_probe.reset();

    // The paper's scenes: 4 × 4 mm membranes of 1k and 3k triangles and a 2k-triangle forceps (jaws open 30°)
    // pushed through until about 40 triangles collide; and one with several hundred colliding triangles.
    std::vector<Scene> scenes(3);
    scenes[0].name = "1k membrane, ~40 colliding";
    scenes[0].membrane = make_membrane_patch(4.0f, 4.0f, kPatch1k.nx, kPatch1k.ny);
    scenes[0].tilt_deg = 45;
    scenes[1].name = "3k membrane, ~40 colliding";
    scenes[1].membrane = make_membrane_patch(4.0f, 4.0f, kPatch3k.nx, kPatch3k.ny);
    scenes[1].tilt_deg = 45;
    scenes[2].name = "3k membrane, several hundred colliding";
    scenes[2].membrane = make_membrane_patch(4.0f, 4.0f, kPatch3k.nx, kPatch3k.ny);
    const size_t targets[3] = {40, 40, 200};
    for (size_t i = 0; i < scenes.size(); ++i) calibrate(scenes[i], forceps, targets[i]);

    std::printf("# eyesim collision benchmark\n\nforceps %zu triangles, jaws open 30°; EGL renderer: %s; "
                "%d timed queries per row (median, p90), membrane vertices move every query\n\n",
                forceps.instrument().mesh.triangle_count(), renderer.c_str(), repeats);
    for (const Scene& s : scenes)
        std::printf("- %s: %zu triangles, approach %.0f° from the normal, tip %.3f mm below the membrane, "
                    "V = ±%.2f mm laterally, %.2f mm below the tip to %.2f mm above it (π = membrane normal), "
                    "exact colliding set %zu triangles\n",
                    s.name.c_str(), s.membrane.triangle_count(), s.tilt_deg, s.depth_mm, s.half_width_mm, s.ahead_mm,
                    s.behind_mm, s.exact.size());
    std::printf("\n| scene | method | R | wall median µs | wall p90 µs | thread-CPU median µs | speed-up vs FCL refit "
                "| found | recall | precision |\n|---|---|---|---|---|---|---|---|---|---|\n");

    for (Scene& s : scenes) {
        forceps.set_state(s.opening_deg, s.pose);
        const TriangleMesh& mem = s.membrane;
        // The membrane "deforms" every query: alternate two vertex sets 0.1 µm apart, so refits do real work
        // while the colliding set stays the same.
        std::vector<Vec3f> base = mem.vertices_mm, wobble = mem.vertices_mm;
        for (size_t v = 0; v < wobble.size(); ++v) wobble[v].z() += 1e-4f * std::sin(float(v));
        std::vector<Vec3f> verts = base;
        auto prepare_verts = [&](int i) { verts = (i & 1) ? wobble : base; };
        const Eigen::Isometry3f pose = s.pose;
        std::vector<Row> rows;
        std::vector<uint32_t> got;
        got.reserve(mem.triangle_count());

        // --- FCL BVHModel<OBBRSS>: refit and rebuild, all triangle pairs reported (no contact points).
        using Model = fcl::BVHModel<fcl::OBBRSSd>;
        auto to_fcl = [](const std::vector<Vec3f>& v) {
            std::vector<fcl::Vector3d> out(v.size());
            for (size_t i = 0; i < v.size(); ++i) out[i] = v[i].cast<double>();
            return out;
        };
        std::vector<fcl::Triangle> mem_tris, ins_tris;
        for (const auto& t : mem.triangles) mem_tris.emplace_back(t[0], t[1], t[2]);
        for (const auto& t : forceps.instrument().mesh.triangles) ins_tris.emplace_back(t[0], t[1], t[2]);
        std::vector<Vec3f> ins_local(forceps.vertices_local_mm().begin(), forceps.vertices_local_mm().end());
        auto ins_model = std::make_shared<Model>();
        ins_model->beginModel();
        ins_model->addSubModel(to_fcl(ins_local), ins_tris);
        ins_model->endModel();
        fcl::Transform3d ins_tf = fcl::Transform3d::Identity();
        ins_tf.linear() = pose.linear().cast<double>();
        ins_tf.translation() = pose.translation().cast<double>();
        const auto fcl_base = to_fcl(base), fcl_wobble = to_fcl(wobble);
        auto mem_model = std::make_shared<Model>();
        mem_model->beginModel();
        mem_model->addSubModel(fcl_base, mem_tris);
        mem_model->endModel();
        fcl::CollisionRequestd req(100000, false);
        fcl::CollisionResultd res;
        auto fcl_collect = [&](const std::shared_ptr<Model>& m) {
            fcl::CollisionObjectd a(m, fcl::Transform3d::Identity()), b(ins_model, ins_tf);
            res.clear();
            fcl::collide(&a, &b, req, res);
            got.clear();
            for (size_t k = 0; k < res.numContacts(); ++k) got.push_back(uint32_t(res.getContact(k).b1));
        };
        Row fr{s.name, "FCL OBBRSS refit + collide", 0};
        fr.t = time_it(repeats, [](int) {}, [&](int i) {
            mem_model->beginUpdateModel();
            mem_model->updateSubModel((i & 1) ? fcl_wobble : fcl_base);
            mem_model->endUpdateModel(true, true);
            fcl_collect(mem_model);
        });
        fcl_collect(mem_model);
        fr.q = quality(got, s.exact);
        const Timing fcl_refit = fr.t;
        rows.push_back(fr);
        Row fb{s.name, "FCL OBBRSS rebuild + collide", 0};
        fb.t = time_it(std::max(5, repeats / 4), [](int) {}, [&](int i) {
            auto m = std::make_shared<Model>();
            m->beginModel();
            m->addSubModel((i & 1) ? fcl_wobble : fcl_base, mem_tris);
            m->endModel();
            fcl_collect(m);
        });
        fb.q = fr.q;
        rows.push_back(fb);

        // --- Bullet GImpact quantized BVH over the membrane (refit per query), pair search against the
        // forceps' BVH, then the exact triangle test on candidate pairs.
        std::vector<int> mem_idx, ins_idx;
        for (const auto& t : mem.triangles) mem_idx.insert(mem_idx.end(), {int(t[0]), int(t[1]), int(t[2])});
        for (const auto& t : forceps.instrument().mesh.triangles) ins_idx.insert(ins_idx.end(), {int(t[0]), int(t[1]), int(t[2])});
        btTriangleIndexVertexArray mem_array(int(mem.triangle_count()), mem_idx.data(), 3 * sizeof(int),
                                             int(verts.size()), reinterpret_cast<btScalar*>(verts.data()), sizeof(Vec3f));
        btTriangleIndexVertexArray ins_array(int(ins_tris.size()), ins_idx.data(), 3 * sizeof(int),
                                             int(ins_local.size()), reinterpret_cast<btScalar*>(ins_local.data()),
                                             sizeof(Vec3f));
        btGImpactMeshShapePart mem_part(&mem_array, 0), ins_part(&ins_array, 0);
        mem_part.setMargin(0);
        ins_part.setMargin(0);
        mem_part.updateBound();
        ins_part.updateBound();
        btTransform ins_bt;
        ins_bt.setIdentity();
        {
            const Eigen::Matrix3f r = pose.linear();
            ins_bt.setBasis(btMatrix3x3(r(0, 0), r(0, 1), r(0, 2), r(1, 0), r(1, 1), r(1, 2), r(2, 0), r(2, 1), r(2, 2)));
            ins_bt.setOrigin(btVector3(pose.translation().x(), pose.translation().y(), pose.translation().z()));
        }
        btTransform ident;
        ident.setIdentity();
        btPairSet pairs;
        std::vector<Vec3f> ins_eye(ins_local.size());
        std::vector<uint32_t> stamp(mem.triangle_count(), 0);
        uint32_t q = 0;
        auto bullet_query = [&]() {
            mem_part.postUpdate();
            mem_part.updateBound();  // refit
            pairs.clear();
            btGImpactQuantizedBvh::find_collision(mem_part.getBoxSet(), ident, ins_part.getBoxSet(), ins_bt, pairs);
            for (size_t i = 0; i < ins_local.size(); ++i) ins_eye[i] = pose * ins_local[i];
            got.clear();
            ++q;
            for (int k = 0; k < pairs.size(); ++k) {
                const uint32_t mt = uint32_t(pairs[k].m_index1);
                if (stamp[mt] == q) continue;
                const auto& a = mem.triangles[mt];
                const auto& b = forceps.instrument().mesh.triangles[size_t(pairs[k].m_index2)];
                if (triangles_intersect(verts[a[0]], verts[a[1]], verts[a[2]], ins_eye[b[0]], ins_eye[b[1]], ins_eye[b[2]])) {
                    stamp[mt] = q;
                    got.push_back(mt);
                }
            }
        };
        Row br{s.name, "Bullet GImpact refit + pairs + tri-tri", 0};
        br.t = time_it(repeats, prepare_verts, [&](int) { bullet_query(); });
        verts = base;
        bullet_query();
        br.q = quality(got, s.exact);
        rows.push_back(br);

        // --- Exact grid narrow phase (the reference), timed as well.
        ExactNarrowPhase exact(mem.triangle_count(), ins_tris.size());
        Row er{s.name, "exact grid (tri-tri + inside)", 0};
        const MeshRef ins_ref{forceps.vertices_local_mm(), forceps.instrument().mesh.triangles, pose};
        er.t = time_it(repeats, prepare_verts, [&](int) {
            const MeshRef m{verts, mem.triangles, Eigen::Isometry3f::Identity()};
            exact.colliding_triangles(m, ins_ref, forceps.instrument().part_triangle_begin, ExactOptions{});
        });
        er.q = quality(s.exact, s.exact);
        rows.push_back(er);

        // --- ZCOLL, CPU and EGL, R = 16 … 256, push mode (features, Eq. 1), and boolean mode at R = 32.
        for (int backend = 0; backend < 2; ++backend) {
            for (int r : {16, 32, 64, 128, 256}) {
                ZcollConfig cfg;
                cfg.resolution_px = r;
                std::unique_ptr<ZcollRasterBackend> be;
                if (backend == 1) {
                    std::string err;
                    be = eyesim::render::GlesZcollBackend::create(err);
                    if (!be) continue;
                }
                ZcollEngine engine(mem, cfg, std::move(be));
                const ZcollView view = scene_view(s, r);
                Row zr{s.name, backend == 0 ? "ZCOLL CPU push" : "ZCOLL EGL push", r};
                size_t sink = 0;
                zr.t = time_it(backend == 0 ? repeats : std::max(5, repeats / 4), prepare_verts,
                               [&](int) { sink += engine.push(verts, forceps, view).colliding_triangles.size(); });
                verts = base;
                const ZcollResult& res_z = engine.push(verts, forceps, view);
                zr.q = quality({res_z.colliding_triangles.begin(), res_z.colliding_triangles.end()}, s.exact);
                if (!res_z.pi_convex) zr.method += " (fallback)";
                rows.push_back(zr);
                if (r == 32) {
                    Row bo{s.name, backend == 0 ? "ZCOLL CPU boolean" : "ZCOLL EGL boolean", r};
                    bool any = false;
                    bo.t = time_it(backend == 0 ? repeats : std::max(5, repeats / 4), prepare_verts,
                                   [&](int) { any |= engine.collides(verts, forceps, view); });
                    bo.q.found = any ? 1 : 0;
                    bo.q.recall = any ? 1.0 : 0.0;
                    bo.q.precision = any ? 1.0 : 0.0;
                    rows.push_back(bo);
                }
                if (sink == 0) std::fprintf(stderr, "note: %s R=%d found nothing\n", s.name.c_str(), r);
            }
        }
        // The paper's camera: π along the instrument axis (V as wide, reaching back over the same depth).
        for (int r : {32, 256}) {
            ZcollConfig cfg;
            cfg.resolution_px = r;
            ZcollEngine engine(mem, cfg);
            const float reach = s.behind_mm / std::max(0.2f, std::cos(s.tilt_deg * kPi / 180.0f));
            const ZcollView view = make_tip_view(pose, s.half_width_mm, s.ahead_mm, std::min(reach, 6.0f), r);
            Row zr{s.name, "ZCOLL CPU push, π = instrument axis", r};
            zr.t = time_it(repeats, prepare_verts, [&](int) { engine.push(verts, forceps, view); });
            verts = base;
            const ZcollResult& res_z = engine.push(verts, forceps, view);
            zr.q = quality({res_z.colliding_triangles.begin(), res_z.colliding_triangles.end()}, s.exact);
            if (!res_z.pi_convex) zr.method += " (fallback)";
            rows.push_back(zr);
        }
        for (const Row& row : rows) print_row(row, fcl_refit);
    }
    std::printf("\nrecall/precision: colliding membrane triangles against the exact set (triangle–triangle "
                "intersections plus triangles inside the instrument); boolean rows report only whether a "
                "collision was found (1 = yes).\n");
    return 0;
}
