#pragma once
/// \file
/// The force kernel's view of the springs: a copy of the hot spring data in structure-of-arrays form, ordered so
/// that neighbouring springs never share a node.
///
/// Why: summing spring forces into nodes is a read-modify-write per end. In mesh order consecutive springs
/// share nodes, so every update waits for the previous store (a chain through memory, ~10 cycles a spring).
/// A greedy edge colouring puts springs that share a node into different colour classes; the schedule lists
/// the classes one after another, so within a class the updates are independent and four springs go through
/// the vector unit together. Node data comes padded to 16 bytes (padded_vec3.hpp).

#include "eyesim/sim/tissue/padded_vec3.hpp"
#include "eyesim/sim/tissue/spring.hpp"

#include <cstddef>
#include <cstdint>
#include <span>
#include <vector>

namespace eyesim::sim::tissue {

/// Springs in kernel order. Built from the dense spring array by `build`; `spring[j]` names the spring that
/// slot j holds (kNoIndex for the padding slots that round the length up to a multiple of 4: they join node
/// 0 to itself with zero stiffness and add nothing).
struct SpringSchedule {
    std::vector<uint32_t> a, b;            ///< node indices per slot
    std::vector<float> rest_mm;            ///< rest length per slot
    std::vector<float> stiffness_nN_per_mm;
    std::vector<float> damping_nN_s_per_mm;
    std::vector<uint32_t> spring;          ///< spring index per slot, kNoIndex for padding
    uint32_t colours = 0;                  ///< colour classes used
    std::vector<uint32_t> class_begin;     ///< first slot of each colour class, then the spring count

    /// Rebuilds the schedule. Allocation-free once the capacities have been reached.
    void build(std::span<const Spring> springs, size_t node_count);

    /// True when the schedule holds exactly `springs` (every spring once, with its current parameters).
    bool matches(std::span<const Spring> springs) const;

private:
    std::vector<uint64_t> used_;      // per node: colours already taken by its springs
    std::vector<uint8_t> colour_;     // per spring
    std::vector<uint32_t> start_;     // per colour: first slot
};

/// Implementations of the scheduled force kernel. All three do the same IEEE operations in the same order
/// (no fused multiply-add), so their results are bitwise equal: a recording replays identically on any x86-64.
enum class SpringKernel {
    kPortable,  ///< one spring at a time, plain C++ (any CPU)
    kSse2,      ///< four springs a block, SSE2 (every x86-64)
    kAvx,       ///< the same in VEX encoding (x86-64 with AVX)
};
/// The fastest kernel this CPU runs (chosen once).
SpringKernel best_spring_kernel();
/// True when this build and CPU can run the kernel.
bool spring_kernel_available(SpringKernel kernel);
/// "portable", "sse2", "avx".
const char* to_string(SpringKernel kernel);

/// Adds the forces of the scheduled springs at (x, v) to f: f_a += F, f_b −= F with
/// F = (k (|d| − L) + c (d̂·(v_b − v_a))) d̂, d = x_b − x_a; springs of zero length add nothing.
/// The fourth lanes of x and v must be 0. Runs `best_spring_kernel()`.
void accumulate_scheduled_spring_forces(const SpringSchedule& schedule, const Float4* x_mm,
                                        const Float4* v_mm_per_s, Float4* f_nN);
/// The same with a chosen kernel (an unavailable one falls back to the best).
void accumulate_scheduled_spring_forces(const SpringSchedule& schedule, const Float4* x_mm,
                                        const Float4* v_mm_per_s, Float4* f_nN, SpringKernel kernel);

}  // namespace eyesim::sim::tissue
