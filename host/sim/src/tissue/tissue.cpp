#include "eyesim/sim/tissue/tissue.hpp"

#include <Eigen/Geometry>

#include <algorithm>
#include <cmath>

namespace eyesim::sim::tissue {

Tissue::Tissue(const TriangleMesh& mesh, const MaterialParams& material, const TissueParams& params,
               IntegratorKind integrator)
    : Tissue(MassSpringSystem::from_mesh(mesh, material), params, integrator) {}

Tissue::Tissue(MassSpringSystem system, const TissueParams& params, IntegratorKind integrator)
    : sys_(std::move(system)), params_(params), integrator_(make_integrator(integrator)) {
    const size_t n = sys_.node_count();
    injection_nN_ = sys_.ext_nN;
    grabbed_.reserve(n);
    grabbed_prev_.reserve(n);
    grabbed_offset_mm_.reserve(n);
    fixed_nodes_.reserve(n);
    scratch_nodes_.reserve(n);
    scratch_springs_.reserve(sys_.spring_count());
}

void Tissue::set_node_state(std::span<const uint32_t> nodes, NodeState s) {
    for (uint32_t v : nodes)
        if (v < sys_.node_count() && sys_.state[v] != NodeState::kRemoved) sys_.set_state(v, s);
    fixed_nodes_.clear();
    for (uint32_t v = 0; v < sys_.node_count(); ++v)
        if (sys_.state[v] == NodeState::kFixed) fixed_nodes_.push_back(v);
}

size_t Tissue::fix_rim() {
    scratch_nodes_.clear();
    for (size_t k = 0; k < sys_.spring_count(); ++k)
        if (sys_.spring_info[k].kind == SpringKind::kEdge && sys_.spring_info[k].tri[1] == kNoIndex) {
            scratch_nodes_.push_back(sys_.springs[k].a);
            scratch_nodes_.push_back(sys_.springs[k].b);
        }
    std::sort(scratch_nodes_.begin(), scratch_nodes_.end());
    scratch_nodes_.erase(std::unique(scratch_nodes_.begin(), scratch_nodes_.end()), scratch_nodes_.end());
    set_node_state(scratch_nodes_, NodeState::kFixed);
    return scratch_nodes_.size();
}

void Tissue::attach_all() {
    for (uint32_t v = 0; v < sys_.node_count(); ++v)
        if (sys_.state[v] != NodeState::kRemoved) sys_.set_state(v, NodeState::kAttached);
    fixed_nodes_.clear();
}

void Tissue::set_integrator(IntegratorKind kind) {
    if (kind != integrator_->kind()) integrator_ = make_integrator(kind);
}

void Tissue::set_constant_force(uint32_t node, const Vec3f& f_nN) {
    if (node >= sys_.node_count() || !f_nN.allFinite()) return;
    sys_.ext_nN[node] += f_nN - injection_nN_[node];  // keep any suction share of this step
    injection_nN_[node] = f_nN;
}

void Tissue::push(std::span<const NodePush> pushes) {
    for (const NodePush& p : pushes) {
        if (p.node >= sys_.node_count() || !is_dynamic(sys_.state[p.node])) continue;
        if (!p.push_mm.allFinite()) continue;  // a corrupt collision result must not poison the state
        sys_.x_mm[p.node] += p.push_mm;
    }
}

void Tissue::set_forceps(const ForcepsInput& in) {
    if (!tool_initialised_ || (in.closed && !forceps_.closed)) tip_prev_mm_ = in.tip_mm;
    tool_initialised_ = true;
    tip_now_mm_ = in.tip_mm;
    if (in.closed && !forceps_.closed) {
        // Closing: bind dynamic nodes within the capture radius to the tip.
        const float r2 = in.grab_radius_mm * in.grab_radius_mm;
        for (uint32_t v = 0; v < sys_.node_count(); ++v) {
            if (!is_dynamic(sys_.state[v]) || (sys_.x_mm[v] - in.tip_mm).squaredNorm() > r2) continue;
            grabbed_.push_back(v);
            grabbed_prev_.push_back(sys_.state[v]);
            grabbed_offset_mm_.push_back(sys_.x_mm[v] - in.tip_mm);
            sys_.set_state(v, NodeState::kGrabbed);
        }
    } else if (!in.closed && forceps_.closed) {
        // Opening: release, keeping the tip's velocity.
        for (size_t k = 0; k < grabbed_.size(); ++k) {
            const uint32_t v = grabbed_[k];
            if (sys_.state[v] != NodeState::kGrabbed) continue;
            const Vec3f vel = sys_.v_mm_per_s[v];
            sys_.set_state(v, grabbed_prev_[k]);
            sys_.v_mm_per_s[v] = vel;
        }
        grabbed_.clear();
        grabbed_prev_.clear();
        grabbed_offset_mm_.clear();
    }
    forceps_ = in;
}

void Tissue::apply_cutter() {
    if (!cutter_.on) return;
    scratch_nodes_.clear();
    const float r2 = cutter_.radius_mm * cutter_.radius_mm;
    for (uint32_t v = 0; v < sys_.node_count(); ++v)
        if (sys_.state[v] != NodeState::kRemoved && (sys_.x_mm[v] - cutter_.centre_mm).squaredNorm() <= r2)
            scratch_nodes_.push_back(v);
    if (scratch_nodes_.empty()) return;
    const uint32_t first = scratch_nodes_.front();
    const TopologyDelta d = sys_.remove({}, scratch_nodes_);
    damage_.nodes_cut += d.nodes_removed;
    damage_.triangles_cut += d.triangles_removed;
    damage_.removed_area_mm2 += d.area_removed_mm2;
    events_.push({TissueEventKind::kTissueRemoved, first, d.nodes_removed, d.area_removed_mm2});
}

void Tissue::apply_needle() {
    if (!needle_.inserted) return;
    // Tear warning: needle velocity projected on the retina's tangent plane at x0.
    const Vec3f radial = needle_.tip_mm - params_.container_centre_mm;
    Vec3f tangential = needle_.velocity_mm_per_s;
    if (radial.squaredNorm() > 0.0f) {
        const Vec3f nrm = radial.normalized();
        tangential -= tangential.dot(nrm) * nrm;
    }
    const float speed = tangential.norm();
    if (speed > params_.tear_warning_speed_mm_per_s)
        events_.merge_max({TissueEventKind::kTearWarning, kNoIndex, kNoIndex, speed});
    // Injection: detach attached nodes within d = c·p and give them a constant force along x_i − x0.
    const float p = needle_.pressure;
    if (!(p > params_.detach_pressure_min)) return;
    const float d = params_.detach_radius_mm_per_pressure * p;
    const float fmag = params_.injection_force_nN_per_pressure * p;
    for (uint32_t v = 0; v < sys_.node_count(); ++v) {
        if (sys_.state[v] != NodeState::kAttached) continue;
        const Vec3f r = sys_.x_mm[v] - needle_.tip_mm;
        if (r.squaredNorm() > d * d) continue;
        sys_.set_state(v, NodeState::kDetached);
        const float rn = r.norm();
        // A node at x0 itself is pushed along the inward retina normal (toward the eye centre).
        const Vec3f dir = rn > 1e-6f ? Vec3f(r / rn)
                                     : (radial.squaredNorm() > 0.0f ? Vec3f(-radial.normalized()) : Vec3f::UnitZ());
        injection_nN_[v] = fmag * dir;
        sys_.ext_nN[v] = injection_nN_[v];
        ++damage_.nodes_detached;
    }
}

void Tissue::apply_tearing_rule() {
    const float a_max = params_.a_max_mm_per_s2, p_tear = params_.p_tear_percent;
    if (!(a_max < kUnlimited) || !(p_tear < kUnlimited)) return;
    const float thr = a_max * (1.0f + p_tear / 100.0f);
    const float thr2 = thr * thr;
    scratch_springs_.clear();
    const size_t n = sys_.node_count();
    for (uint32_t i = 0; i < n; ++i) {
        const NodeState st = sys_.state[i];
        if (!is_dynamic(st) && st != NodeState::kGrabbed) continue;
        const float im = sys_.inv_mass_per_mg[i];
        const float a2 = sys_.f_nN[i].squaredNorm() * im * im;
        if (!(a2 > thr2)) continue;
        // Overloaded: find the spring exerting the largest force on node i.
        uint32_t best = kNoIndex;
        float best_f = -1.0f;
        Vec3f best_fa = Vec3f::Zero();
        for (uint32_t j = sys_.node_spring_begin[i]; j < sys_.node_spring_begin[i + 1]; ++j) {
            const uint32_t k = sys_.node_springs[j];
            const Spring& sp = sys_.springs[k];
            const Vec3f d = sys_.x_mm[sp.b] - sys_.x_mm[sp.a];
            const float len = d.norm();
            if (!(len > 1e-12f)) continue;
            const Vec3f nrm = d / len;
            const float mag = sp.stiffness_nN_per_mm * (len - sp.rest_mm) +
                              sp.damping_nN_s_per_mm * nrm.dot(sys_.v_mm_per_s[sp.b] - sys_.v_mm_per_s[sp.a]);
            if (std::abs(mag) > best_f) {
                best_f = std::abs(mag);
                best = k;
                best_fa = mag * nrm;
            }
        }
        if (best == kNoIndex) continue;
        // Already torn by an earlier node this substep: its load has been relieved, tear nothing more here.
        if (std::find(scratch_springs_.begin(), scratch_springs_.end(), best) != scratch_springs_.end()) continue;
        scratch_springs_.push_back(best);
        const Spring& sp = sys_.springs[best];
        sys_.f_nN[sp.a] -= best_fa;  // the torn spring no longer acts in this step
        sys_.f_nN[sp.b] += best_fa;
        events_.push({TissueEventKind::kSpringTorn, i, sp.a == i ? sp.b : sp.a, std::sqrt(a2)});
    }
    if (scratch_springs_.empty()) return;
    damage_.springs_torn += scratch_springs_.size();
    const TopologyDelta d = sys_.remove(scratch_springs_, {});
    damage_.triangles_torn += d.triangles_removed;
    damage_.torn_area_mm2 += d.area_removed_mm2;
}

void Tissue::substep(float dt, float frac_end) {
    // 1. Kinematic tool nodes: grabbed nodes follow the tip, interpolated across the frame.
    if (!grabbed_.empty()) {
        const Vec3f tip = tip_prev_mm_ + frac_end * (tip_now_mm_ - tip_prev_mm_);
        for (size_t k = 0; k < grabbed_.size(); ++k) {
            const uint32_t v = grabbed_[k];
            if (sys_.state[v] != NodeState::kGrabbed) continue;
            const Vec3f target = tip + grabbed_offset_mm_[k];
            sys_.v_mm_per_s[v] = (target - sys_.x_mm[v]) / dt;
            sys_.x_mm[v] = target;
        }
    }
    // 2. External loads: constant injection forces plus, while on, vitrector suction ∝ 1/distance in the cone.
    if (suction_.on) {
        const Vec3f axis = suction_.axis.normalized();
        const float cos_half = std::cos(suction_.half_angle_deg * 3.14159265f / 180.0f);
        const float range2 = suction_.range_mm * suction_.range_mm;
        for (uint32_t v = 0; v < sys_.node_count(); ++v) {
            sys_.ext_nN[v] = injection_nN_[v];
            if (!is_dynamic(sys_.state[v])) continue;
            const Vec3f r = sys_.x_mm[v] - suction_.apex_mm;
            const float d2 = r.squaredNorm();
            if (d2 > range2 || d2 <= 0.0f) continue;
            const float d = std::sqrt(d2);
            if (r.dot(axis) < cos_half * d) continue;  // outside the cone
            const float mag = suction_.strength_nN_mm / std::max(d, params_.suction_min_distance_mm);
            sys_.ext_nN[v] -= (mag / d) * r;  // toward the apex
        }
        ext_has_suction_ = true;
    } else if (ext_has_suction_) {
        sys_.ext_nN.assign(injection_nN_);
        ext_has_suction_ = false;
    }
    // 3. Forces at the current state.
    sys_.compute_forces(params_);
    // 4. Lift-off warning: net force on fixed rim nodes.
    if (params_.lift_off_force_nN < kUnlimited) {
        for (uint32_t v : fixed_nodes_) {
            if (sys_.state[v] != NodeState::kFixed) continue;
            const float f = sys_.f_nN[v].norm();
            if (f > params_.lift_off_force_nN) events_.merge_max({TissueEventKind::kLiftOff, v, kNoIndex, f});
        }
    }
    // 5. The paper's tearing rule, then integration.
    apply_tearing_rule();
    integrator_->advance(sys_, params_, dt);
}

void Tissue::step(float frame_dt_s, int substeps) {
    events_.clear();
    if (!(frame_dt_s > 0.0f) || !std::isfinite(frame_dt_s) || substeps < 1) return;
    if (!tool_initialised_) tip_prev_mm_ = tip_now_mm_;
    apply_cutter();
    apply_needle();
    const float dt = frame_dt_s / float(substeps);
    for (int s = 0; s < substeps; ++s) substep(dt, float(s + 1) / float(substeps));
    tip_prev_mm_ = tip_now_mm_;
}

bool Tissue::write_to(TriangleMesh& mesh) {
    const bool rebuild = written_topology_version_ != sys_.topology_version ||
                         mesh.vertices_mm.size() != sys_.node_count();
    sys_.write_to(mesh, rebuild);
    written_topology_version_ = sys_.topology_version;
    return rebuild;
}

}  // namespace eyesim::sim::tissue
