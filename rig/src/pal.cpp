#include "eyesim/rig/pal.hpp"

namespace eyesim::rig {

FieldTiming field_timing(int64_t index, double field_time_offset_us, double exposure_us, int first_field_parity) {
    FieldTiming t;
    t.index = index;
    t.parity = static_cast<int>((first_field_parity + (index & 1)) & 1);
    t.start_us = field_time_offset_us + static_cast<double>(index) * kFieldPeriodUs;
    t.exposure_end_us = t.start_us;
    t.exposure_start_us = t.start_us - exposure_us;
    t.exposure_mid_us = t.start_us - 0.5 * exposure_us;
    t.end_us = t.line_end_us(kFieldHeight - 1);
    return t;
}

}  // namespace eyesim::rig
