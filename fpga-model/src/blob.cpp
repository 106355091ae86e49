#include "eyesim/fpga/blob.hpp"

#include "eyesim/fpga/timing.hpp"

namespace eyesim::fpga {

// Central moments from raw sums: μ20/μ00 = Σwx²/Σw − x̄².
double Blob::mu20_px2() const {
    if (sum_w == 0) return 0.0;
    const double m = static_cast<double>(sum_w), x = sum_wx / m;
    return sum_wxx / m - x * x;
}

double Blob::mu02_px2() const {
    if (sum_w == 0) return 0.0;
    const double m = static_cast<double>(sum_w), y = sum_wy / m;
    return sum_wyy / m - y * y;
}

double Blob::mu11_px2() const {
    if (sum_w == 0) return 0.0;
    const double m = static_cast<double>(sum_w);
    return sum_wxy / m - (sum_wx / m) * (sum_wy / m);
}

double Blob::latency_us() const { return cycles_to_us(latency_cycles); }

}  // namespace eyesim::fpga
