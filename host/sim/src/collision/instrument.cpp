#include "eyesim/sim/collision/instrument.hpp"

#include <cmath>
#include <utility>

namespace eyesim::sim::collision {
namespace {

constexpr float kPi = 3.14159265358979f;

/// Appends a closed loft: `loops` cross-sections of `ring` points each (loop k at points[k·ring ..]), quads
/// between consecutive loops, both ends closed by fans around their centroids. Orientation is fixed afterwards
/// from the signed volume so every part has outward normals whatever order the caller used.
void add_loft(Instrument& ins, const std::vector<Vec3f>& points, int loops, int ring, InstrumentPart part) {
    TriangleMesh& m = ins.mesh;
    const uint32_t base = uint32_t(m.vertices_mm.size());
    const uint32_t first_tri = uint32_t(m.triangles.size());
    for (const Vec3f& p : points) {
        m.vertices_mm.push_back(p);
        ins.vertex_part.push_back(part);
    }
    auto id = [&](int k, int s) { return base + uint32_t(k * ring + (s % ring)); };
    for (int k = 0; k + 1 < loops; ++k)
        for (int s = 0; s < ring; ++s) {
            m.triangles.push_back({id(k, s), id(k, s + 1), id(k + 1, s + 1)});
            m.triangles.push_back({id(k, s), id(k + 1, s + 1), id(k + 1, s)});
        }
    for (int end = 0; end < 2; ++end) {
        const int k = end == 0 ? 0 : loops - 1;
        Vec3f c = Vec3f::Zero();
        for (int s = 0; s < ring; ++s) c += points[size_t(k * ring + s)];
        c /= float(ring);
        const uint32_t ci = uint32_t(m.vertices_mm.size());
        m.vertices_mm.push_back(c);
        ins.vertex_part.push_back(part);
        for (int s = 0; s < ring; ++s) {
            if (end == 0) m.triangles.push_back({ci, id(k, s + 1), id(k, s)});
            else m.triangles.push_back({ci, id(k, s), id(k, s + 1)});
        }
    }
    double vol = 0;
    for (size_t t = first_tri; t < m.triangles.size(); ++t) {
        const auto& tr = m.triangles[t];
        vol += double(m.vertices_mm[tr[0]].dot(m.vertices_mm[tr[1]].cross(m.vertices_mm[tr[2]])));
    }
    if (vol < 0)
        for (size_t t = first_tri; t < m.triangles.size(); ++t) std::swap(m.triangles[t][1], m.triangles[t][2]);
    ins.part_triangle_begin.push_back(uint32_t(m.triangles.size()));
}

/// Circular tube loops along z from z0 to z1 (`loops` loops), radius(k) per loop, centred on (cx, cy).
std::vector<Vec3f> tube(float z0, float z1, int loops, int ring, float cx, float cy, float (*radius)(float),
                        float r_scale) {
    std::vector<Vec3f> p;
    p.reserve(size_t(loops * ring));
    for (int k = 0; k < loops; ++k) {
        const float u = float(k) / float(loops - 1);
        const float z = z0 + (z1 - z0) * u;
        const float r = r_scale * radius(u);
        for (int s = 0; s < ring; ++s) {
            const float a = 2.0f * kPi * float(s) / float(ring);
            p.emplace_back(cx + r * std::cos(a), cy + r * std::sin(a), z);
        }
    }
    return p;
}

float constant_radius(float) { return 1.0f; }

Instrument start(InstrumentKind kind) {
    Instrument ins;
    ins.kind = kind;
    ins.part_triangle_begin.push_back(0);
    return ins;
}

void finish(Instrument& ins) { ins.mesh.build_adjacency(); }

/// Shaft tube length behind the working end: the part inside the eye.
constexpr float kShaftLength_mm = 12.0f;

}  // namespace

std::string_view instrument_name(InstrumentKind kind) {
    switch (kind) {
        case InstrumentKind::Forceps: return "forceps";
        case InstrumentKind::Vitrector: return "vitrector";
        case InstrumentKind::Pick: return "pick";
        case InstrumentKind::InjectionNeedle: return "injection_needle";
        case InstrumentKind::LightPipe: return "light_pipe";
    }
    return "unknown";
}

Instrument make_forceps() {
    Instrument ins = start(InstrumentKind::Forceps);
    const float jaw_len = 1.5f;
    ins.hinge_local_mm = Vec3f(0, 0, -jaw_len);
    ins.shaft_radius_mm = 0.3f;
    add_loft(ins, tube(-kShaftLength_mm, -jaw_len + 0.1f, 23, 24, 0, 0, constant_radius, 0.3f), 23, 24,
             InstrumentPart::Shaft);
    // Jaws: tapered boxes from the hinge to the tip; closed, they meet on the x = 0 plane.
    const int loops = 56;
    for (int j = 0; j < 2; ++j) {
        const float side = j == 0 ? 1.0f : -1.0f;
        std::vector<Vec3f> p;
        for (int k = 0; k < loops; ++k) {
            const float u = float(k) / float(loops - 1);
            const float z = -jaw_len + jaw_len * u;
            const float half_w = 0.2f - 0.1f * u;       // y half-width 0.2 → 0.1 mm
            const float thick = 0.16f - 0.08f * u;      // x thickness 0.16 → 0.08 mm
            const float x0 = 0.0f, x1 = side * thick;
            p.emplace_back(x0, -half_w, z);
            p.emplace_back(x1, -half_w, z);
            p.emplace_back(x1, half_w, z);
            p.emplace_back(x0, half_w, z);
        }
        add_loft(ins, p, loops, 4, j == 0 ? InstrumentPart::JawA : InstrumentPart::JawB);
    }
    finish(ins);
    return ins;
}

Instrument make_vitrector() {
    Instrument ins = start(InstrumentKind::Vitrector);
    const int ring = 32, loops = 31;
    const float r = 0.3f;
    // Tube from the back to the tip; the last 0.3 mm close into a hemispherical end at z = 0.
    std::vector<Vec3f> p;
    for (int k = 0; k < loops; ++k) {
        float z, rk;
        if (k < loops - 6) {
            z = -kShaftLength_mm + (kShaftLength_mm - r) * float(k) / float(loops - 7);
            rk = r;
        } else {
            const float a = 0.5f * kPi * float(k - (loops - 7)) / 6.0f;  // 0 .. just below π/2
            z = -r + r * std::sin(a * 0.97f);
            rk = r * std::cos(a * 0.97f);
        }
        for (int s = 0; s < ring; ++s) {
            const float az = 2.0f * kPi * float(s) / float(ring);
            float rr = rk;
            // Side opening: a recessed window facing +x, 0.25–0.75 mm behind the tip, ±40° wide.
            const float daz = std::atan2(std::sin(az), std::cos(az));
            if (z > -0.75f && z < -0.25f && std::fabs(daz) < 0.7f) rr = 0.18f;
            p.emplace_back(rr * std::cos(az), rr * std::sin(az), z);
        }
    }
    add_loft(ins, p, loops, ring, InstrumentPart::Shaft);
    // The loft's front fan centre sits at the end point of the dome; put the tip exactly there.
    ins.port_local_mm = Vec3f(0.18f, 0, -0.5f);
    ins.port_dir_local = Vec3f(1, 0, 0);
    ins.shaft_radius_mm = r;
    finish(ins);
    return ins;
}

Instrument make_pick() {
    Instrument ins = start(InstrumentKind::Pick);
    const float r = 0.3f;
    add_loft(ins, tube(-kShaftLength_mm, -0.5f, 27, 32, 0, 0, constant_radius, r), 27, 32, InstrumentPart::Shaft);
    // Hook: a cone from inside the shaft end to a point 0.35 mm off-axis (+x) at z = 0.
    const int loops = 8, ring = 16;
    const Vec3f base(0, 0, -0.6f), apex(0.35f, 0, 0);
    const Vec3f axis = (apex - base).normalized();
    const Vec3f u = axis.cross(Vec3f::UnitY()).normalized(), v = axis.cross(u);
    std::vector<Vec3f> p;
    for (int k = 0; k < loops; ++k) {
        const float t = float(k) / float(loops - 1);
        const float rk = 0.12f * (1.0f - t) + 0.004f * t;
        const Vec3f c = base + (apex - base) * t;
        for (int s = 0; s < ring; ++s) {
            const float a = 2.0f * kPi * float(s) / float(ring);
            p.push_back(c + rk * (std::cos(a) * u + std::sin(a) * v));
        }
    }
    add_loft(ins, p, loops, ring, InstrumentPart::Shaft);
    for (Vec3f& q : ins.mesh.vertices_mm) q -= apex;  // the hook point is the tip
    ins.shaft_radius_mm = r;
    finish(ins);
    return ins;
}

Instrument make_injection_needle() {
    Instrument ins = start(InstrumentKind::InjectionNeedle);
    const float r = 0.15f, bevel = 0.6f;  // the bevel rises 0.6 mm across the diameter
    const int ring = 32, loops = 31;
    std::vector<Vec3f> p;
    for (int k = 0; k < loops; ++k) {
        const float t = float(k) / float(loops - 1);
        for (int s = 0; s < ring; ++s) {
            const float a = 2.0f * kPi * float(s) / float(ring);
            const float x = r * std::cos(a), y = r * std::sin(a);
            const float z_end = -bevel * (r - x) / (2.0f * r);  // tip point at x = +r, z = 0
            p.emplace_back(x, y, -kShaftLength_mm + (z_end + kShaftLength_mm) * t);
        }
    }
    add_loft(ins, p, loops, ring, InstrumentPart::Shaft);
    for (Vec3f& q : ins.mesh.vertices_mm) q.x() -= r;
    ins.shaft_radius_mm = r;
    finish(ins);
    return ins;
}

Instrument make_light_pipe() {
    Instrument ins = start(InstrumentKind::LightPipe);
    const float r = 0.35f;
    add_loft(ins, tube(-kShaftLength_mm, 0.0f, 31, 32, 0, 0, constant_radius, r), 31, 32, InstrumentPart::Shaft);
    ins.shaft_radius_mm = r;
    finish(ins);
    return ins;
}

Instrument make_rigid_instrument(TriangleMesh mesh, std::vector<uint32_t> part_triangle_begin) {
    Instrument ins;
    ins.kind = InstrumentKind::Pick;
    if (part_triangle_begin.empty()) part_triangle_begin = {0u, uint32_t(mesh.triangle_count())};
    ins.part_triangle_begin = std::move(part_triangle_begin);
    ins.vertex_part.assign(mesh.vertex_count(), InstrumentPart::Shaft);
    ins.mesh = std::move(mesh);
    if (ins.mesh.vertex_triangle_begin.empty()) ins.mesh.build_adjacency();
    return ins;
}

Instrument make_instrument(InstrumentKind kind) {
    switch (kind) {
        case InstrumentKind::Forceps: return make_forceps();
        case InstrumentKind::Vitrector: return make_vitrector();
        case InstrumentKind::Pick: return make_pick();
        case InstrumentKind::InjectionNeedle: return make_injection_needle();
        case InstrumentKind::LightPipe: return make_light_pipe();
    }
    return make_pick();
}

void Instrument::articulate(float opening_deg, std::span<Vec3f> out_local_mm) const {
    const auto& v = mesh.vertices_mm;
    if (kind != InstrumentKind::Forceps || opening_deg == 0.0f) {
        for (size_t i = 0; i < v.size(); ++i) out_local_mm[i] = v[i];
        return;
    }
    // Each jaw turns by half the opening about +y through the hinge; jaw A (x ≥ 0) opens towards +x.
    const float half = 0.5f * opening_deg * kPi / 180.0f;
    const float c = std::cos(half), s = std::sin(half);
    for (size_t i = 0; i < v.size(); ++i) {
        const InstrumentPart part = vertex_part[i];
        if (part == InstrumentPart::Shaft) {
            out_local_mm[i] = v[i];
            continue;
        }
        const float sg = part == InstrumentPart::JawA ? s : -s;
        const Vec3f d = v[i] - hinge_local_mm;
        out_local_mm[i] = hinge_local_mm + Vec3f(d.x() * c + d.z() * sg, d.y(), -d.x() * sg + d.z() * c);
    }
}

PosedInstrument::PosedInstrument(Instrument instrument)
    : instrument_(std::move(instrument)), vertices_(instrument_.mesh.vertices_mm) {}

void PosedInstrument::set_state(float opening_deg, const Eigen::Isometry3f& instrument_to_eye) {
    pose_ = instrument_to_eye;
    if (opening_deg != opening_deg_) {
        instrument_.articulate(opening_deg, vertices_);
        opening_deg_ = opening_deg;
    }
}

}  // namespace eyesim::sim::collision
