#pragma once
/// \file
/// One detected marker, as the benchmarks' contenders report it.

namespace eyesim::fpga::bench {

/// One detected marker.
struct Detection {
    int cls;   ///< colour class 1..4
    double x;  ///< centroid, field px
    double y;  ///< centroid, field px
};

}  // namespace eyesim::fpga::bench
