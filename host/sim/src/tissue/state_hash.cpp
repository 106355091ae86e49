#include "eyesim/sim/tissue/state_hash.hpp"

namespace eyesim::sim::tissue {

namespace {

void fnv1a(uint64_t& h, const void* data, size_t bytes) {
    const auto* p = static_cast<const unsigned char*>(data);
    for (size_t i = 0; i < bytes; ++i) {
        h ^= p[i];
        h *= 0x100000001b3ull;
    }
}

}  // namespace

uint64_t state_hash(const MassSpringSystem& sys) {
    uint64_t h = 0xcbf29ce484222325ull;
    for (size_t i = 0; i < sys.node_count(); ++i) fnv1a(h, sys.x_mm.lanes()[i].v, 3 * sizeof(float));
    for (size_t i = 0; i < sys.node_count(); ++i) fnv1a(h, sys.v_mm_per_s.lanes()[i].v, 3 * sizeof(float));
    fnv1a(h, sys.state.data(), sys.state.size() * sizeof(NodeState));
    for (const Spring& s : sys.springs) {
        fnv1a(h, &s.a, sizeof s.a);
        fnv1a(h, &s.b, sizeof s.b);
    }
    return h;
}

}  // namespace eyesim::sim::tissue
