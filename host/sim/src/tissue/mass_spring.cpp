#include "eyesim/sim/tissue/mass_spring.hpp"

#include <Eigen/Geometry>

#include <algorithm>
#include <cmath>
#include <unordered_map>

namespace eyesim::sim::tissue {

namespace {

uint64_t edge_key(uint32_t a, uint32_t b) {
    if (a > b) std::swap(a, b);
    return (uint64_t{a} << 32) | b;
}

}  // namespace

MassSpringSystem MassSpringSystem::from_mesh(const TriangleMesh& mesh, const MaterialParams& material) {
    MassSpringSystem s;
    const size_t n = mesh.vertex_count();
    s.x_mm.assign(mesh.vertices_mm);
    s.v_mm_per_s.assign(n, Vec3f::Zero());
    s.f_nN.assign(n, Vec3f::Zero());
    s.ext_nN.assign(n, Vec3f::Zero());
    s.state.assign(n, NodeState::kFree);
    s.node_had_triangles.assign(n, 0);

    // Node masses: a third of each adjacent triangle's area.
    std::vector<float> mass(n, 0.0f);
    s.triangles = mesh.triangles;
    s.triangle_alive.assign(mesh.triangle_count(), 1);
    s.triangle_rest_area_mm2.resize(mesh.triangle_count());
    for (size_t t = 0; t < mesh.triangle_count(); ++t) {
        const auto& tri = mesh.triangles[t];
        const float area =
            0.5f * (mesh.vertices_mm[tri[1]] - mesh.vertices_mm[tri[0]])
                       .cross(mesh.vertices_mm[tri[2]] - mesh.vertices_mm[tri[0]])
                       .norm();
        s.triangle_rest_area_mm2[t] = area;
        for (uint32_t v : tri) {
            mass[v] += material.areal_density_mg_per_mm2 * area / 3.0f;
            s.node_had_triangles[v] = 1;
        }
    }
    s.inv_mass_per_mg.resize(n);
    for (size_t i = 0; i < n; ++i) s.inv_mass_per_mg[i] = mass[i] > 0.0f ? 1.0f / mass[i] : 0.0f;
    s.mass_mg = mass;
    s.w_per_mg = s.inv_mass_per_mg;
    for (size_t i = 0; i < n; ++i)
        if (!s.node_had_triangles[i]) s.state[i] = NodeState::kRemoved, s.w_per_mg[i] = 0.0f;

    // Edge springs in first-seen order, linked to their triangles.
    std::unordered_map<uint64_t, uint32_t> edge_spring;
    edge_spring.reserve(mesh.triangle_count() * 2);
    s.triangle_springs.resize(mesh.triangle_count());
    for (uint32_t t = 0; t < mesh.triangle_count(); ++t) {
        const auto& tri = mesh.triangles[t];
        for (int k = 0; k < 3; ++k) {
            const uint32_t a = tri[k], b = tri[(k + 1) % 3];
            auto [it, inserted] = edge_spring.emplace(edge_key(a, b), uint32_t(s.springs.size()));
            if (inserted) {
                const float len = (mesh.vertices_mm[a] - mesh.vertices_mm[b]).norm();
                s.springs.push_back({std::min(a, b), std::max(a, b), material.rest_length_scale * len,
                                     material.edge_stiffness_nN_per_mm, material.edge_damping_nN_s_per_mm});
                SpringInfo info;
                info.kind = SpringKind::kEdge;
                info.tri[0] = t;
                s.spring_info.push_back(info);
            } else {
                s.spring_info[it->second].tri[1] = t;  // a manifold edge has at most two triangles
            }
            s.triangle_springs[t][k] = it->second;
        }
    }

    // Bending springs: across each interior edge, between the two opposite vertices.
    if (material.bending_stiffness_nN_per_mm > 0.0f) {
        const size_t edge_count = s.springs.size();
        for (size_t e = 0; e < edge_count; ++e) {
            const SpringInfo info = s.spring_info[e];
            if (info.tri[1] == kNoIndex) continue;
            auto opposite = [&](uint32_t t) {
                for (uint32_t v : mesh.triangles[t])
                    if (v != s.springs[e].a && v != s.springs[e].b) return v;
                return kNoIndex;
            };
            const uint32_t p = opposite(info.tri[0]), q = opposite(info.tri[1]);
            if (p == kNoIndex || q == kNoIndex || p == q) continue;
            const float len = (mesh.vertices_mm[p] - mesh.vertices_mm[q]).norm();
            s.springs.push_back({std::min(p, q), std::max(p, q), material.rest_length_scale * len,
                                 material.bending_stiffness_nN_per_mm, material.bending_damping_nN_s_per_mm});
            SpringInfo b;
            b.kind = SpringKind::kBending;
            b.tri[0] = info.tri[0];
            b.tri[1] = info.tri[1];
            s.spring_info.push_back(b);
        }
    }
    s.rebuild_incidence();
    return s;
}

MassSpringSystem MassSpringSystem::from_springs(std::span<const Vec3f> x_mm, std::span<const float> mass_mg,
                                                std::span<const Spring> springs) {
    MassSpringSystem s;
    const size_t n = x_mm.size();
    s.x_mm.assign(x_mm);
    s.v_mm_per_s.assign(n, Vec3f::Zero());
    s.f_nN.assign(n, Vec3f::Zero());
    s.ext_nN.assign(n, Vec3f::Zero());
    s.state.assign(n, NodeState::kFree);
    s.node_had_triangles.assign(n, 0);
    s.inv_mass_per_mg.resize(n);
    for (size_t i = 0; i < n; ++i) s.inv_mass_per_mg[i] = mass_mg[i] > 0.0f ? 1.0f / mass_mg[i] : 0.0f;
    s.mass_mg.resize(n);
    for (size_t i = 0; i < n; ++i) s.mass_mg[i] = mass_mg[i] > 0.0f ? mass_mg[i] : 0.0f;
    s.w_per_mg = s.inv_mass_per_mg;
    s.springs.assign(springs.begin(), springs.end());
    s.spring_info.assign(springs.size(), SpringInfo{});
    s.rebuild_incidence();
    return s;
}

size_t MassSpringSystem::live_triangle_count() const {
    return size_t(std::count(triangle_alive.begin(), triangle_alive.end(), uint8_t{1}));
}

void MassSpringSystem::set_state(uint32_t node, NodeState s) {
    state[node] = s;
    w_per_mg[node] = is_dynamic(s) ? inv_mass_per_mg[node] : 0.0f;
    if (!is_dynamic(s)) v_mm_per_s[node].setZero();
}

void accumulate_spring_forces(std::span<const Spring> springs, const PaddedVec3Array& x,
                              const PaddedVec3Array& v, PaddedVec3Array& f) {
    for (const Spring& s : springs) {
        // Axial elastic + axial damping force, one sqrt per spring.
        const Vec3f d = x[s.b] - x[s.a];
        const float len2 = d.squaredNorm();
        if (!(len2 > 1e-24f)) continue;  // coincident nodes: no defined direction, no force
        const float inv_len = 1.0f / std::sqrt(len2);
        const Vec3f n = d * inv_len;
        const float stretch = len2 * inv_len - s.rest_mm;
        const float rate = n.dot(v[s.b] - v[s.a]);
        const Vec3f fa = (s.stiffness_nN_per_mm * stretch + s.damping_nN_s_per_mm * rate) * n;
        f[s.a] += fa;
        f[s.b] -= fa;
    }
}

void MassSpringSystem::compute_forces(const TissueParams& p) {
    const size_t n = node_count();
    if (schedule.spring.size() != ((springs.size() + 3) & ~size_t{3})) rebuild_incidence();
    // Body forces, four lanes a node (the padding lanes of v and ext are 0, so f's stays 0).
    const Eigen::Vector4f g(p.gravity_mm_per_s2.x(), p.gravity_mm_per_s2.y(), p.gravity_mm_per_s2.z(), 0.0f);
    const float drag = p.drag_per_s;
    const Float4* __restrict v = v_mm_per_s.lanes();
    const Float4* __restrict ext = ext_nN.lanes();
    const float* __restrict m = mass_mg.data();
    Float4* __restrict f = f_nN.lanes();
    using C4 = Eigen::Map<const Eigen::Vector4f, Eigen::Aligned16>;
    for (size_t i = 0; i < n; ++i)
        Eigen::Map<Eigen::Vector4f, Eigen::Aligned16>(f[i].v) = C4(ext[i].v) + m[i] * (g - drag * C4(v[i].v));
    accumulate_scheduled_spring_forces(schedule, x_mm.lanes(), v, f);
}

void MassSpringSystem::rebuild_incidence() {
    const size_t n = node_count();
    node_spring_begin.assign(n + 1, 0);
    for (const Spring& s : springs) ++node_spring_begin[s.a + 1], ++node_spring_begin[s.b + 1];
    for (size_t i = 0; i < n; ++i) node_spring_begin[i + 1] += node_spring_begin[i];
    node_springs.resize(node_spring_begin[n]);
    scratch_remap_.assign(node_spring_begin.begin(), node_spring_begin.end() - 1);  // fill cursors
    for (uint32_t k = 0; k < springs.size(); ++k) {
        node_springs[scratch_remap_[springs[k].a]++] = k;
        node_springs[scratch_remap_[springs[k].b]++] = k;
    }
    schedule.build(springs, n);
}

TopologyDelta MassSpringSystem::remove(std::span<const uint32_t> spring_ids, std::span<const uint32_t> node_ids) {
    TopologyDelta delta;
    if (spring_ids.empty() && node_ids.empty()) return delta;
    const size_t ns = springs.size();
    scratch_spring_dead_.assign(ns, 0);
    for (uint32_t k : spring_ids) scratch_spring_dead_[k] = 1;
    for (uint32_t v : node_ids) {
        if (state[v] == NodeState::kRemoved) continue;
        set_state(v, NodeState::kRemoved);
        ++delta.nodes_removed;
        for (uint32_t j = node_spring_begin[v]; j < node_spring_begin[v + 1]; ++j)
            scratch_spring_dead_[node_springs[j]] = 1;
    }
    // 1. Triangles die with any node or edge spring.
    for (size_t t = 0; t < triangles.size(); ++t) {
        if (!triangle_alive[t]) continue;
        bool dead = false;
        for (int k = 0; k < 3; ++k)
            dead = dead || state[triangles[t][k]] == NodeState::kRemoved || scratch_spring_dead_[triangle_springs[t][k]];
        if (dead) {
            triangle_alive[t] = 0;
            ++delta.triangles_removed;
            delta.area_removed_mm2 += triangle_rest_area_mm2[t];
        }
    }
    // 2. Springs die with their triangles (edge: all of them; bending: either).
    auto alive = [&](uint32_t t) { return t != kNoIndex && triangle_alive[t]; };
    for (size_t k = 0; k < ns; ++k) {
        const SpringInfo& info = spring_info[k];
        if (info.kind == SpringKind::kEdge && !alive(info.tri[0]) && !alive(info.tri[1])) scratch_spring_dead_[k] = 1;
        if (info.kind == SpringKind::kBending && !(alive(info.tri[0]) && alive(info.tri[1])))
            scratch_spring_dead_[k] = 1;
    }
    // 3. Nodes that had triangles and have none left are removed (their springs are already dead, see header).
    if (delta.triangles_removed > 0) {
        scratch_remap_.assign(node_count(), 0);  // live triangle count per node
        for (size_t t = 0; t < triangles.size(); ++t)
            if (triangle_alive[t])
                for (uint32_t v : triangles[t]) ++scratch_remap_[v];
        for (uint32_t v = 0; v < node_count(); ++v)
            if (node_had_triangles[v] && scratch_remap_[v] == 0 && state[v] != NodeState::kRemoved) {
                set_state(v, NodeState::kRemoved);
                ++delta.nodes_removed;
            }
    }
    // 4. Compact springs in order; remap triangle → spring links.
    scratch_remap_.assign(ns, kNoIndex);
    uint32_t out = 0;
    for (uint32_t k = 0; k < ns; ++k) {
        if (scratch_spring_dead_[k]) continue;
        scratch_remap_[k] = out;
        springs[out] = springs[k];
        spring_info[out] = spring_info[k];
        ++out;
    }
    delta.springs_removed = uint32_t(ns - out);
    springs.resize(out);
    spring_info.resize(out);
    for (size_t t = 0; t < triangles.size(); ++t)
        for (int k = 0; k < 3; ++k)
            triangle_springs[t][k] = triangle_alive[t] ? scratch_remap_[triangle_springs[t][k]] : kNoIndex;
    rebuild_incidence();
    ++topology_version;
    return delta;
}

void MassSpringSystem::write_to(TriangleMesh& mesh, bool rebuild_topology) const {
    mesh.vertices_mm.resize(x_mm.size());
    for (size_t i = 0; i < x_mm.size(); ++i) mesh.vertices_mm[i] = x_mm[i];
    if (!rebuild_topology) return;
    mesh.triangles.clear();
    for (size_t t = 0; t < triangles.size(); ++t)
        if (triangle_alive[t]) mesh.triangles.push_back(triangles[t]);
    mesh.build_adjacency();
}

bool MassSpringSystem::check_consistency(const char** why) const {
    auto fail = [&](const char* w) {
        if (why) *why = w;
        return false;
    };
    const size_t n = node_count();
    if (v_mm_per_s.size() != n || f_nN.size() != n || w_per_mg.size() != n || state.size() != n)
        return fail("node arrays differ in length");
    if (spring_info.size() != springs.size()) return fail("spring arrays differ in length");
    if (!schedule.matches(springs)) return fail("force schedule out of date with the springs");
    for (size_t k = 0; k < springs.size(); ++k) {
        const Spring& s = springs[k];
        if (s.a >= n || s.b >= n || s.a == s.b) return fail("spring node index out of range");
        if (state[s.a] == NodeState::kRemoved || state[s.b] == NodeState::kRemoved)
            return fail("spring attached to a removed node");
        const SpringInfo& info = spring_info[k];
        auto alive = [&](uint32_t t) { return t != kNoIndex && t < triangles.size() && triangle_alive[t]; };
        if (info.kind == SpringKind::kEdge && !alive(info.tri[0]) && !alive(info.tri[1]))
            return fail("edge spring without a live triangle");
        if (info.kind == SpringKind::kBending && !(alive(info.tri[0]) && alive(info.tri[1])))
            return fail("bending spring across a dead triangle");
    }
    std::vector<uint32_t> live_tris(n, 0);
    for (size_t t = 0; t < triangles.size(); ++t) {
        if (!triangle_alive[t]) continue;
        for (int k = 0; k < 3; ++k) {
            const uint32_t v = triangles[t][k];
            if (v >= n || state[v] == NodeState::kRemoved) return fail("live triangle uses a removed node");
            ++live_tris[v];
            const uint32_t sk = triangle_springs[t][k];
            if (sk >= springs.size()) return fail("live triangle lost an edge spring");
            const uint32_t a = triangles[t][k], b = triangles[t][(k + 1) % 3];
            if (!((springs[sk].a == a && springs[sk].b == b) || (springs[sk].a == b && springs[sk].b == a)))
                return fail("triangle edge linked to the wrong spring");
        }
    }
    for (size_t v = 0; v < n; ++v)
        if (node_had_triangles[v] && state[v] != NodeState::kRemoved && live_tris[v] == 0)
            return fail("live node without a live triangle");
    for (size_t v = 0; v < n; ++v) {
        if (!std::isfinite(x_mm[v].sum()) || !std::isfinite(v_mm_per_s[v].sum())) return fail("non-finite state");
        if (!is_dynamic(state[v]) && w_per_mg[v] != 0.0f) return fail("kinematic node with inverse mass");
    }
    return true;
}

double MassSpringSystem::kinetic_energy() const {
    double e = 0.0;
    for (size_t i = 0; i < node_count(); ++i)
        if (is_dynamic(state[i]) && inv_mass_per_mg[i] > 0.0f)
            e += 0.5 * double(v_mm_per_s[i].squaredNorm()) / double(inv_mass_per_mg[i]);
    return e;
}

double MassSpringSystem::elastic_energy() const {
    double e = 0.0;
    for (const Spring& s : springs) {
        const double stretch = double((x_mm[s.b] - x_mm[s.a]).norm()) - double(s.rest_mm);
        e += 0.5 * double(s.stiffness_nN_per_mm) * stretch * stretch;
    }
    return e;
}

}  // namespace eyesim::sim::tissue
