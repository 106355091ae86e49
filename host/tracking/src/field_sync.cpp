#include "eyesim/tracking/field_sync.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

namespace eyesim::tracking {

SyncMode sync_mode_from_name(std::string_view name) {
    if (name == "interpolate") return SyncMode::Interpolate;
    if (name == "extrapolate") return SyncMode::Extrapolate;
    if (name == "nearest") return SyncMode::Nearest;
    if (name == "async") return SyncMode::Async;
    throw std::invalid_argument("unknown synchronisation mode '" + std::string(name) + "'");
}

// ---------------------------------------------------------------------------------------------------------------
// FieldAssembler
// ---------------------------------------------------------------------------------------------------------------

void FieldAssembler::start(const protocol::FieldMarkers& msg) {
    building_.camera = msg.camera_id;
    building_.field_counter = msg.field_counter;
    building_.parity = msg.field_parity & 1;
    building_.field_end_device_us = 0;
    building_.received_host_us = 0;
    building_.blobs_dropped = false;
    building_.incomplete = false;
    building_.count = 0;
    building_.overflow = 0;
    latest_complete_us_ = 0;
    next_part_ = 0;
    active_ = true;
}

void FieldAssembler::append(const protocol::FieldMarkers& msg, double received_host_us) {
    if (msg.part_index != next_part_) building_.incomplete = true;  // a part was lost
    next_part_ = std::uint16_t(msg.part_index + 1);
    building_.received_host_us = std::max(building_.received_host_us, received_host_us);
    if (msg.flags & protocol::kFieldFlagBlobsDropped) building_.blobs_dropped = true;
    if (msg.field_end_us) building_.field_end_device_us = double(msg.field_end_us);
    const int n = std::min<int>(msg.marker_count, int(protocol::kMaxMarkersPerMessage));
    for (int i = 0; i < n; ++i) {
        const protocol::Marker& m = msg.markers[std::size_t(i)];
        latest_complete_us_ = std::max(latest_complete_us_, double(m.complete_us));
        if (m.colour_class < protocol::kMinColourClass || m.colour_class > protocol::kMaxColourClass) {
            ++rejected_;
            continue;
        }
        if (building_.count >= kMaxMarkersPerCamera) {
            ++building_.overflow;
            continue;
        }
        FieldImage& im = building_.images[std::size_t(building_.count++)];
        im.colour_class = m.colour_class;
        im.flags = m.flags;
        const double x = double(m.x_q16) / protocol::kCoordScale;
        const double y = double(m.y_q16) / protocol::kCoordScale;
        im.frame_px = Eigen::Vector2d(x, 2.0 * y + building_.parity);  // field row y of parity p = frame row 2y+p
        im.area_px = float(m.area_px);
    }
}

void FieldAssembler::finish(const CameraTiming& timing, bool incomplete, int slot) {
    CameraField& f = done_[std::size_t(slot)];
    f = building_;
    f.incomplete = f.incomplete || incomplete;
    // Low-latency parts carry no field end until the last part; a lost last part leaves the newest blob time.
    if (f.field_end_device_us <= 0.0) f.field_end_device_us = latest_complete_us_;
    f.sample_device_us = f.field_end_device_us - timing.end_to_sample_us[std::size_t(f.parity)];
    active_ = false;
}

int FieldAssembler::push(const protocol::FieldMarkers& msg, double received_host_us, const CameraTiming& timing) {
    int done = 0;
    if (active_ && (msg.field_counter != building_.field_counter || msg.part_index == 0)) finish(timing, true, done++);
    if (!active_) start(msg);
    append(msg, received_host_us);
    if (!(msg.flags & protocol::kFieldFlagMoreFollows)) finish(timing, false, done++);
    return done;
}

// ---------------------------------------------------------------------------------------------------------------
// FrameSync
// ---------------------------------------------------------------------------------------------------------------

FrameSync::FrameSync(int camera_count, const SyncOptions& opt)
    : n_(std::clamp(camera_count, 0, kMaxCameras)), opt_(opt) {}

const CameraField* FrameSync::at(int cam, int age) const {
    const Ring& r = rings_[std::size_t(cam)];
    if (age < 0 || age >= r.count) return nullptr;
    return &r.f[std::size_t((r.head - 1 - age + 2 * kHistory) % kHistory)];
}

void FrameSync::add(const CameraField& f) {
    if (f.camera < 0 || f.camera >= n_ || !std::isfinite(f.sample_device_us)) return;
    Ring& r = rings_[std::size_t(f.camera)];
    // Out-of-order or repeated fields are ignored: the ring is kept in time order.
    if (r.count > 0 && f.sample_device_us <= r.latest_sample_us) return;
    r.f[std::size_t(r.head)] = f;
    r.head = (r.head + 1) % kHistory;
    r.count = std::min(r.count + 1, kHistory);
    r.latest_sample_us = f.sample_device_us;
    newest_device_us_ = std::max(newest_device_us_, f.field_end_device_us);
    if (f.camera != opt_.reference_camera) return;
    // Schedule frames: one per reference field, and one per reference field that went missing (its time from
    // the field period), so a lost reference field still gives a (two-view) frame.
    auto schedule = [&](double T, std::uint32_t counter) {
        if (pending_count_ == kMaxPending) {  // consumer too slow: drop the oldest
            std::move(pending_.begin() + 1, pending_.end(), pending_.begin());
            --pending_count_;
        }
        pending_[std::size_t(pending_count_++)] = {T, counter, f.field_end_device_us};
    };
    if (have_ref_) {
        const std::uint32_t gap = f.field_counter - last_ref_counter_;
        if (gap > 1 && gap <= 4)
            for (std::uint32_t k = 1; k < gap; ++k)
                schedule(last_ref_T_ + double(k) * (f.sample_device_us - last_ref_T_) / double(gap),
                         last_ref_counter_ + k);
    }
    schedule(f.sample_device_us, f.field_counter);
    have_ref_ = true;
    last_ref_counter_ = f.field_counter;
    last_ref_T_ = f.sample_device_us;
}

bool FrameSync::has_field_at(int cam, double T) const {
    if (cam < 0 || cam >= n_) return false;
    for (int age = 0; age < rings_[std::size_t(cam)].count; ++age)
        if (std::abs(at(cam, age)->sample_device_us - T) <= opt_.max_skew_us) return true;
    return false;
}

bool FrameSync::field_due(int cam, double T) const {
    if (cam < 0 || cam >= n_) return false;
    const Ring& r = rings_[std::size_t(cam)];
    if (r.count == 0 || r.latest_sample_us > T - opt_.max_skew_us) return false;
    // Its period from its last two fields, the nominal one where a field between them was lost.
    const CameraField* prev = at(cam, 1);
    const double nominal = opt_.field_period_us;
    double period = prev ? r.latest_sample_us - prev->sample_device_us : nominal;
    if (!(period > 0.5 * nominal && period < 1.5 * nominal)) period = nominal;
    // Its first field time from T − max_skew_us on.
    const double next = r.latest_sample_us + period * std::ceil((T - opt_.max_skew_us - r.latest_sample_us) / period);
    return next <= T + opt_.max_skew_us;
}

bool FrameSync::decided(int cam, double T) const {
    const Ring& r = rings_[std::size_t(cam)];
    if (r.count > 0 && r.latest_sample_us > T - 1.0) return true;  // a field at T or after it
    if (opt_.mode == SyncMode::Interpolate) return false;
    // The other modes use fields at or before T only, so they wait for no later field; but a field exposed with
    // T's (a genlocked rig) is the one they need.
    return cam == opt_.reference_camera || !field_due(cam, T);
}

bool FrameSync::ready() const {
    if (pending_count_ == 0) return false;
    const double T = pending_[0].T;
    if (finished_ || newest_device_us_ > T + opt_.max_wait_us) return true;
    // A field due with T's that has not come by half a period after the reference field's end is lost.
    if (opt_.mode != SyncMode::Interpolate && newest_device_us_ > pending_[0].end_us + 0.5 * opt_.field_period_us)
        return true;
    for (int c = 0; c < n_; ++c)
        if (!decided(c, T)) return false;
    return true;
}

namespace {

/// Pairs the images of two fields of one camera (same class, mutual nearest within the gate) and writes
/// p0 + α·(p1 − p0) for each pair. With `fp` and `fpp` (the two fields before f0) and `sigma_px` > 0, an image
/// that pairs back through both gets the quadratic's term c·(T − t0)(T − t1) (SyncOptions::curvature): c the mean
/// of the second divided differences over (fpp, fp, f0) and (fp, f0, f1), which cancels a bias that alternates
/// with the field parity (a second difference of three fields amplifies it fourfold), shrunk by c²/(c² + var c).
/// Returns the number of images of the nearer field left unpaired.
int blend(const CameraField& f0, const CameraField& f1, double alpha, double gate_px, CameraField& out,
          const CameraField* fp = nullptr, const CameraField* fpp = nullptr, double sigma_px = 0.0) {
    out.count = 0;
    std::array<int, kMaxMarkersPerCamera> best01{}, best10{};
    best01.fill(-1);
    best10.fill(-1);
    auto nearest = [gate_px](const CameraField& a, int i, const CameraField& b) {
        int best = -1;
        double bd = gate_px;
        for (int j = 0; j < b.count; ++j) {
            if (b.images[std::size_t(j)].colour_class != a.images[std::size_t(i)].colour_class) continue;
            const double d = (b.images[std::size_t(j)].frame_px - a.images[std::size_t(i)].frame_px).norm();
            if (d < bd) { bd = d; best = j; }
        }
        return best;
    };
    for (int i = 0; i < f0.count; ++i) best01[std::size_t(i)] = nearest(f0, i, f1);
    for (int j = 0; j < f1.count; ++j) best10[std::size_t(j)] = nearest(f1, j, f0);
    // c = w1·p1 + w0·p0 + wp·pp + wpp·ppp (px/s², times in s), its noise var σ²·Σw².
    const double t1 = f1.sample_device_us * 1e-6, t0 = f0.sample_device_us * 1e-6;
    const double tp = fp ? fp->sample_device_us * 1e-6 : 0.0, tpp = fpp ? fpp->sample_device_us * 1e-6 : 0.0;
    const bool bend = fp && fpp && sigma_px > 0.0 && t1 - t0 > 1e-6 && t0 - tp > 1e-6 && tp - tpp > 1e-6;
    double w1 = 0, w0 = 0, wp = 0, wpp = 0, var_c = 0;
    if (bend) {
        // f[a,b,c] = ((pc − pb)/(tc − tb) − (pb − pa)/(tb − ta))/(tc − ta); the mean of two, each weighted ½.
        const double A = 0.5 / (t1 - tp), B = 0.5 / (t0 - tpp);
        w1 = A / (t1 - t0);
        w0 = -A / (t1 - t0) - A / (t0 - tp) + B / (t0 - tp);
        wp = A / (t0 - tp) - B / (t0 - tp) - B / (tp - tpp);
        wpp = B / (tp - tpp);
        var_c = sigma_px * sigma_px * (w1 * w1 + w0 * w0 + wp * wp + wpp * wpp);
    }
    const double T = t0 + alpha * (t1 - t0);
    const double basis_s2 = (T - t0) * (T - t1);
    int paired = 0;
    for (int i = 0; i < f0.count; ++i) {
        const int j = best01[std::size_t(i)];
        if (j < 0 || best10[std::size_t(j)] != i) continue;
        FieldImage& o = out.images[std::size_t(out.count++)];
        o = f0.images[std::size_t(i)];
        o.flags |= f1.images[std::size_t(j)].flags;
        // Occlusion in either field biases the blend: keep the smaller area so it can be detected.
        o.area_px = std::min(o.area_px, f1.images[std::size_t(j)].area_px);
        const Eigen::Vector2d& p0 = f0.images[std::size_t(i)].frame_px;
        const Eigen::Vector2d& p1 = f1.images[std::size_t(j)].frame_px;
        o.frame_px = p0 + alpha * (p1 - p0);
        if (bend) {
            const int k = nearest(f0, i, *fp);
            const int m = k >= 0 && nearest(*fp, k, f0) == i ? nearest(*fp, k, *fpp) : -1;
            if (m >= 0 && nearest(*fpp, m, *fp) == k) {
                const Eigen::Vector2d c = w1 * p1 + w0 * p0 + wp * fp->images[std::size_t(k)].frame_px +
                                          wpp * fpp->images[std::size_t(m)].frame_px;
                for (int a = 0; a < 2; ++a) {
                    const double c2 = c[a] * c[a];
                    o.frame_px[a] += c[a] * (c2 / (c2 + var_c)) * basis_s2;
                }
            }
        }
        ++paired;
    }
    const CameraField& nearer = (alpha < 0.5) ? f0 : f1;
    return nearer.count - paired;
}

}  // namespace

void FrameSync::align(int cam, double T, AlignedCamera& ac, CameraField& out, double& end_us,
                      double& recv_us) const {
    ac = AlignedCamera{};
    out.count = 0;
    out.camera = cam;
    const CameraField* a = nullptr;   // newest at or before T
    const CameraField* a0 = nullptr;  // the one before a
    const CameraField* a1 = nullptr;  // the one before a0
    const CameraField* b = nullptr;   // oldest after T
    const Ring& r = rings_[std::size_t(cam)];
    for (int age = 0; age < r.count; ++age) {
        const CameraField* f = at(cam, age);
        if (f->sample_device_us > T + 1.0) {
            b = f;
        } else if (!a) {
            a = f;
        } else if (!a0) {
            a0 = f;
        } else if (!a1) {
            a1 = f;
        }
    }
    auto use_direct = [&](const CameraField* f) {
        out = *f;
        ac.state = CameraSyncState::Direct;
        ac.dt_us = f->sample_device_us - T;
        ac.field_a = ac.field_b = f->field_counter;
        end_us = std::max(end_us, f->field_end_device_us);
        recv_us = std::max(recv_us, f->received_host_us);
    };
    auto use_pair = [&](const CameraField* f0, const CameraField* f1, CameraSyncState st,
                        const CameraField* fp = nullptr, const CameraField* fpp = nullptr) {
        const double alpha = (T - f0->sample_device_us) / (f1->sample_device_us - f0->sample_device_us);
        ac.dropped_images = blend(*f0, *f1, alpha, opt_.pair_gate_px, out, fp, fpp, opt_.curvature_sigma_px);
        out.camera = cam;
        out.parity = f1->parity;
        out.parity_weight = (f0->parity & 1) == (f1->parity & 1) ? 1.0 : alpha;  // p0 + α·(p1 − p0)
        out.field_counter = f1->field_counter;
        ac.state = st;
        ac.dt_us = (alpha < 0.5 ? f0 : f1)->sample_device_us - T;
        ac.field_a = f0->field_counter;
        ac.field_b = f1->field_counter;
        end_us = std::max(end_us, f1->field_end_device_us);
        recv_us = std::max({recv_us, f0->received_host_us, f1->received_host_us});
    };
    if (a && std::abs(a->sample_device_us - T) < 1.0) {
        use_direct(a);
        return;
    }
    switch (opt_.mode) {
        case SyncMode::Interpolate:
            if (a && b && b->sample_device_us - a->sample_device_us <= opt_.max_gap_us) {
                const bool bend = opt_.curvature && a0 && a1 && a->sample_device_us - a1->sample_device_us <= 2.0 * opt_.max_gap_us;
                use_pair(a, b, CameraSyncState::Interpolated, bend ? a0 : nullptr, bend ? a1 : nullptr);
                return;
            }
            break;
        case SyncMode::Extrapolate:
        case SyncMode::Async:
            if (a && a0 && a->sample_device_us - a0->sample_device_us <= opt_.max_gap_us &&
                T - a->sample_device_us <= opt_.max_gap_us) {
                use_pair(a0, a, CameraSyncState::Extrapolated);
                return;
            }
            break;
        case SyncMode::Nearest: break;
    }
    const CameraField* nearest = nullptr;
    for (const CameraField* f : {a, b})
        if (f && (!nearest || std::abs(f->sample_device_us - T) < std::abs(nearest->sample_device_us - T)))
            nearest = f;
    if (nearest && std::abs(nearest->sample_device_us - T) <= opt_.max_skew_us) use_direct(nearest);
}

bool FrameSync::pop(double& frame_device_us, std::uint32_t& reference_field,
                    std::array<AlignedCamera, kMaxCameras>& cams, std::array<CameraField, kMaxCameras>& images,
                    double& latest_end_device_us, double& latest_received_host_us) {
    if (!ready()) return false;
    const Pending p = pending_[0];
    std::move(pending_.begin() + 1, pending_.begin() + pending_count_, pending_.begin());
    --pending_count_;
    frame_device_us = p.T;
    reference_field = p.ref_field;
    latest_end_device_us = -1e300;
    latest_received_host_us = -1e300;
    for (int c = 0; c < kMaxCameras; ++c) {
        if (c < n_) {
            align(c, p.T, cams[std::size_t(c)], images[std::size_t(c)], latest_end_device_us, latest_received_host_us);
        } else {
            cams[std::size_t(c)] = AlignedCamera{};
            images[std::size_t(c)].count = 0;
        }
    }
    if (latest_end_device_us < -1e299) latest_end_device_us = p.T;
    if (latest_received_host_us < -1e299) latest_received_host_us = 0.0;
    return true;
}

}  // namespace eyesim::tracking
