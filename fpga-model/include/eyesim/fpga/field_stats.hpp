#pragma once
/// \file
/// Per-field counters of the pipeline.

#include <cstdint>

namespace eyesim::fpga {

/// What happened in one field. Reset at begin_field; final after end_field.
struct FieldStats {
    uint32_t field_counter = 0;          ///< from begin_field
    uint32_t lines = 0;                  ///< active lines pushed
    uint32_t runs = 0;                   ///< classified runs extracted
    uint32_t merges = 0;                 ///< label merges (U/W shapes, chains)
    uint32_t blobs_emitted = 0;          ///< blobs that passed the filters and were delivered or queued
    uint32_t blobs_filtered = 0;         ///< completed blobs rejected by area/shape filters
    uint32_t table_overflows = 0;        ///< runs that found no free blob-table slot (dropped)
    uint32_t dropped_blobs = 0;          ///< blobs lost because the output ring was full
    uint32_t max_table_occupancy = 0;    ///< high-water mark of live blob-table slots
    uint32_t max_runs_per_line = 0;      ///< high-water mark of runs on one line
    uint32_t fast_path_pixels = 0;       ///< pixels skipped by the background fast path
    uint32_t ring_pixels = 0;            ///< background pixels added to blobs by the edge ring
    uint32_t last_active_line_end_cycle = 0;  ///< cycle after the last pushed line's last active pixel
    uint32_t last_emit_cycle = 0;        ///< emission cycle of the field's last blob (0: none)
    uint32_t last_blob_latency_cycles = 0;    ///< last_emit_cycle - last_active_line_end_cycle (0 if earlier)
};

}  // namespace eyesim::fpga
