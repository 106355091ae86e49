#pragma once
/// \file
/// Asynchronous fusion (SCAAT after Welch & Bishop): one extended Kalman filter per body, rigid pose and velocity
/// under a constant-velocity model with white acceleration (or, as one model of a mixture, acceleration under
/// white jerk), updated on each camera field on its own at that
/// field's exposure mid-time. Nothing waits for the other cameras: every field corrects the pose as soon as it
/// is assembled, and the pose can be read at the newest observation's time or predicted to any later time.
///
/// State (error-state form, rig frame): orientation R (body→rig) with a rotation error δθ (R = exp(δθ)·R̂),
/// translation t (X_rig = R·b + t; the instrument body origin is its tip), angular velocity ω and velocity v,
/// angular acceleration α and acceleration a (zero in a constant-velocity model).
/// The eye is a rotation about its fixed centre (t = centre, v = 0, no translation noise). Markers on one
/// line (the instruments) leave the roll about that line unobservable: a pseudo-measurement keeps its variance
/// bounded. Fixed-size Eigen throughout, no allocation.

#include "eyesim/tracking/body_model.hpp"
#include "eyesim/tracking/camera_geometry.hpp"

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <array>
#include <algorithm>
#include <cmath>
#include <limits>

namespace eyesim::tracking {

/// Options of the per-body filters and the association of images to predicted markers.
struct AsyncOptions {
    double sigma_x_px = 0.08;         ///< 1σ centroid noise along x (frame pixels)
    double sigma_y_px = 0.12;         ///< 1σ along y (frame pixels: a field's rows are two frame rows apart)
    /// White linear-acceleration spectral density q (mm²/s³) of the instruments' agile motion model (the one
    /// that follows fast turns; with motion_models 1 the only one: the trade between smoothing and following).
    double accel_psd_mm2_s3 = 4.0e3;
    double ang_accel_psd_rad2_s3 = 16.0;  ///< white angular-acceleration spectral density (rad²/s³), agile
    double eye_ang_accel_psd_rad2_s3 = 1.0;  ///< the same for the eye (a heavier, slower body), agile
    /// Motion models each body's filter mixes (IMM, BodyFilter): 1 the agile model alone; 2 the steady and the
    /// agile; 3 also one between them (densities the geometric mean of the two).
    int motion_models = 3;
    /// The steady model's densities: a body held or moved slowly (most of a procedure), where the agile model's
    /// noise would pass the centroid noise straight through to the pose.
    double steady_accel_psd_mm2_s3 = 1.0e2;
    double steady_ang_accel_psd_rad2_s3 = 0.4;
    /// The eye's steady model: white angular acceleration, and (when eye_steady_ang_jerk_psd_rad2_s5 > 0) an
    /// angular acceleration held as a state under white jerk with correlation time eye_steady_accel_correlation_s.
    /// The eye is turned smoothly (the surgeon's instruments through the trocars): a steady constant-velocity model
    /// lags its turns by ≈ α/ω², and the rotation error grew with the eye's angle (the live demo, seed 22: 0.7 % of
    /// the rotation about each axis, 0.018° RMS), which the likelihoods of an agile or a separate acceleration model
    /// never outweighed (96 % on the steady model). With the acceleration in the steady model its white part can
    /// be ten times smaller. Chosen on 2 s `sweep` seeds 1–2, `surgery`, `fast`, `occlusion` seed 1 and the demo's
    /// seed 22 (docs/validation.md, "The eye's steady model follows its turns").
    double eye_steady_ang_accel_psd_rad2_s3 = 1.0e-4;
    double eye_steady_ang_jerk_psd_rad2_s5 = 0.03;
    double eye_steady_accel_correlation_s = 1.0;
    /// The instruments' agile model turns about the trocar while the instrument passes through it (tip inside the
    /// eye, the shaft within trocar_gate_mm of the trocar; RigidBodyFilter::set_pivot): its angular noise moves the
    /// tip through the lever from the trocar, the trocar point itself moving by the model's linear density along
    /// the shaft and pivot_across_fraction of it across (the trocar moves only with the eye), and its prediction
    /// carries the tip along the arc. The steadier models keep independent noise (on held-out `surgery` and
    /// `sweep` a pivot there cost the tip 1–3 %). Chosen on 2 s `fast` seeds 75–80 (across 0.1 / 0.3 / 1) and
    /// checked on `surgery`, `sweep` and `occlusion` seeds 75–78 (docs/validation.md, "The agile model turns
    /// about the trocar").
    bool pivot_model = true;
    double pivot_across_fraction = 0.3;
    /// An instrument that a camera's field before supported and whose next field of that camera shows none of the
    /// two or more markers the filter puts in that image is reported held until a field supports it again (it has
    /// moved out of the gate: pulled out, pushed in; Tracker::fuse_field). With low-latency parts it is decided at
    /// each part over the markers the readout has passed. A field in which the filter refused one of the
    /// instrument's images inside the gate (NIS above nis_gate) is a miss too, and supports nothing. After a miss
    /// only another camera's images since the miss count as the second view of a supporting field (one camera may
    /// look along the motion that caused it).
    bool hold_on_miss = true;
    /// An instrument is reported measured only while two cameras have each given at least `min_markers_good` of its
    /// images within `other_view_fields` periods: two markers in one camera and a single one in another leave its
    /// direction, and the tip 26 mm beyond its markers, loose (`occlusion`: 0.4–0.9 mm off over 0.2 s, σ
    /// 0.10–0.13 mm; docs/validation.md, "An instrument the readout has passed; two views for an instrument").
    bool two_view_support = true;
    /// An instrument acquired from a fit (the filter not yet started) is reported held until a second fit in a row
    /// starts its filter: the first fit, from cameras' fields extrapolated to one time, was up to 1.7 mm off where
    /// an instrument reappeared moving fast (`occlusion`, the cannula re-found after its pull-out).
    bool hold_acquisition_fit = true;
    /// The eye's filter starts from its first acquisition fit, at rest (no rotation rate), instead of waiting for a
    /// second fit in a row and its finite-difference rate (docs/validation.md, "The eye's filter starts from one
    /// fit").
    bool eye_filter_from_one_fit = true;
    /// Fixed-lag reports. 0: each part of the reference camera that corrected a filter gives a frame at once (the
    /// pose at its field's time from what has been fused so far). > 0: one frame per reference field, reported
    /// once the host clock is this long past the field's exposure mid, its poses smoothed by everything fused
    /// since (BodyFilter::smoothed_pose_at; needs time_order_parts' history, else the newest state carried back):
    /// the other cameras' parts exposed after it bracket the frame's time, as interpolation does without waiting
    /// for their whole fields. The host releases a frame when it falls due (Tracker::next_report_host_us, a timer
    /// in the live loop), not with the next message, which can come 3 ms later where markers are few. 19 ms keeps
    /// the 21 ms median with a margin for the host's wake-up; on held-out `fast` recordings the 3D error
    /// over all markers fell from 40 to 24 µm (docs/validation.md, "Fixed-lag frames").
    double report_delay_us = 19000.0;
    /// Its limit: the smoothing needs the filter as it was at the frame's time, and the parts history
    /// (Tracker::kReplayEpochs update times) reaches about 2.7 field periods back.
    static constexpr double kMaxReportDelayUs = 40000.0;
    /// Rate at which the body is expected to switch between steady and agile motion (1/s, each way): the
    /// models' prior mixing (with the images' likelihoods it decides which model the pose follows).
    double model_switch_per_s = 2.0;
    double gate_px = 6.0;             ///< an image farther than this from a predicted marker is not its image
    double ambiguity_ratio = 1.5;     ///< the second-nearest same-class image must be this much farther, else skip
    double nis_gate = 25.0;           ///< normalised innovation squared (2 dof) above this: outlier, not used
    /// A field supports a body when it gives at least this many of its markers (one marker and the trocar leave
    /// an instrument's pose underdetermined, and a filter fed only such fields drifts).
    int min_markers_good = 2;
    double lost_after_us = 100000.0;  ///< no supporting field for this long: the body is lost (re-acquired)
    /// No supporting field for this many field periods: the body's pose is reported held (not measured) and its
    /// markers left out. Under one, so that a frame needs a supporting field since the previous frame's: with
    /// three cameras a third of a period apart, two that see a body give one within two thirds of a period.
    double held_after_fields = 0.75;
    /// A field supports an instrument only if another camera saw one of its markers within this many field
    /// periods: one view leaves the depth along its rays to the motion model.
    double other_view_fields = 1.05;
    double max_position_sigma_mm = 1.0;  ///< √trace of the position covariance above this: lost
    /// An instrument whose position σ (√trace of its filter's position covariance, the tip's) is above this is
    /// reported held: the images that still support it leave its pose loose (out of the eye, no trocar line; one
    /// camera with two markers and another with one), and the filter drifts millimetres while they fit it. A
    /// well-supported instrument's σ is 0.08–0.10 mm; the agile model raises it on fast tilts (at 0.12 mm a
    /// quarter of `fast`'s instrument frames were held). Chosen on 2 s `occlusion` seeds 75–80 and `fast`,
    /// `sweep`, `surgery` seeds 75–77 (docs/validation.md, "An instrument whose filter is unsure is held").
    double held_position_sigma_mm = 0.15;
    double marker_recent_us = 30000.0;   ///< a marker seen by ≥ 2 cameras within this is reported in a frame
    double min_area_ratio = 0.6;      ///< an image whose blob area is below this share of the sphere's: occluded
    /// One more motion model, acceleration under white jerk (a fast turn bends a body's path within the 7–13 ms
    /// between a camera's field and the newest images of the others; a constant-velocity prediction misses by
    /// ½·a·dt²): for the eye, and (off by default) the instruments; its jerk densities, the accelerations' 1σ
    /// when a body is acquired, and their correlation time (a body unseen for a while coasts at its velocity).
    /// Its white acceleration is the steady model's. The instruments' is off: on held-out `fast` recordings it
    /// lowered the markers' error a little and made the tip diverge in some, with parts in time order too
    /// (docs/validation.md).
    bool eye_acceleration_model = true;
    bool acceleration_model = false;
    /// A low-latency part older than a filter's state (cameras whose fields overlap in time send their parts
    /// interleaved) is fused at its own time: the filter goes back to its state before that time (a short history
    /// per body, Tracker::kReplayEpochs update times) and the newer parts are applied again after it; the trocar
    /// line, which always holds, goes to the newest state. Off (or a part older than the history): the part is
    /// fused as an aged observation against the state carried back by the velocities. On held-out `fast`
    /// recordings with parts it halves the 3D error (docs/validation.md, "Low-latency parts in time order").
    bool time_order_parts = true;
    double accel_correlation_s = 0.1;
    double jerk_psd_mm2_s5 = 3.5e8;
    double ang_jerk_psd_rad2_s5 = 4.0e5;
    double eye_ang_jerk_psd_rad2_s5 = 1.0e3;
    double accel0_sigma_mm_s2 = 2000.0;
    double ang_accel0_sigma_rad_s2 = 60.0;
};

class BodyFilter;

/// The constant-velocity models' white-acceleration densities, steadiest first, for `models` of them (clamped to
/// 1..3): the agile alone; the steady and the agile; or also their geometric mean between them. Returns the count.
int motion_model_ladder(int models, double steady, double agile, double* out);

/// Configures `f` as the tracker's eye filter: rotation about `centre_rig_mm`, the motion models and acceleration
/// models `ao` names for the eye (the constant-velocity ladder, its steady model with an acceleration when
/// eye_steady_ang_jerk_psd_rad2_s5 > 0, and the agile acceleration model when eye_acceleration_model).
void configure_eye_filter(BodyFilter& f, const AsyncOptions& ao, const Eigen::Vector3d& centre_rig_mm);

/// SCAAT filter of one rigid body (see the file comment).
class RigidBodyFilter {
public:
    /// Error state: δθ, δt, δω, δv, and the accelerations δα, δa of a constant-acceleration model (held at zero,
    /// with no variance, in a constant-velocity one).
    static constexpr int kDim = 18;
    using State = Eigen::Matrix<double, kDim, 1>;
    /// Its covariance.
    using Cov = Eigen::Matrix<double, kDim, kDim>;
    /// Jacobian of one image by the error state.
    using Jacobian = Eigen::Matrix<double, 2, kDim>;

    /// An instrument-like rigid body (free rotation and translation). `roll_axis_body`: unit axis of a body whose
    /// markers are all on that line (roll unobservable), else zero.
    void configure_rigid(const Eigen::Vector3d& roll_axis_body, double ang_psd_rad2_s3, double lin_psd_mm2_s3);
    /// A body rotating about `centre_rig_mm`, fixed in the rig (the eye).
    void configure_rotation(const Eigen::Vector3d& centre_rig_mm, double ang_psd_rad2_s3);
    /// Makes the motion model one of acceleration: white jerk of these spectral densities (rad²/s⁵, mm²/s⁵) on
    /// top of the white acceleration configured; `sigma_*0`: the accelerations' 1σ when tracking starts;
    /// `correlation_s` > 0: the acceleration fades by exp(−dt / correlation_s) (Singer), else it is held.
    /// Call after configure_*. Densities 0: constant velocity (the default).
    void set_jerk(double ang_jerk_psd_rad2_s5, double lin_jerk_psd_mm2_s5, double sigma_alpha0_rad_s2,
                  double sigma_acc0_mm_s2, double correlation_s);
    /// True for a constant-acceleration model (set_jerk).
    bool constant_acceleration() const { return ca_; }
    /// Makes the body turn about a pivot (an instrument through its trocar): the body point `pivot_body_mm` on its
    /// shaft along `axis_body`; `on` false: no pivot (the default). The white angular acceleration then moves the origin
    /// through the lever from the pivot (correlated with the rotation), the pivot itself moving by the white linear
    /// acceleration along the axis and `across_fraction` of it across; and a prediction carries the origin along
    /// the arc about the pivot (the rotational part of its velocity turns with the body). Why: a tilt accelerated
    /// about the trocar moves the tip and the markers on opposite sides of it, which independent linear and angular
    /// noise cannot tell from a translation (docs/tracking.md, "The agile model turns about the trocar").
    void set_pivot(bool on, const Eigen::Vector3d& pivot_body_mm, const Eigen::Vector3d& axis_body,
                   double across_fraction);

    /// Starts tracking at `t_us` (device clock) with this pose and velocity and 1σ uncertainties.
    void init(double t_us, const Eigen::Quaterniond& R_body_to_rig, const Eigen::Vector3d& t_mm,
              const Eigen::Vector3d& omega_rad_s, const Eigen::Vector3d& v_mm_s, double sigma_rot_rad,
              double sigma_pos_mm, double sigma_omega_rad_s, double sigma_v_mm_s);
    /// Stops tracking (lost).
    void reset() { tracking_ = false; }
    /// True between init() and reset().
    bool tracking() const { return tracking_; }

    /// Moves the state to `t_us` (x + v·dt + ½·a·dt²; the covariance grows with the process noise). A time
    /// before the current one is predicted back the same way (observations older than the state are better
    /// given to update_point with their age, which leaves the state where it is).
    void predict_to(double t_us);
    /// Pose at `t_us` without changing the filter: the motion model itself.
    void pose_at(double t_us, Eigen::Quaterniond& R_body_to_rig, Eigen::Vector3d& t_mm) const;
    /// Display-time prediction: as pose_at, with each velocity shrunk by its own uncertainty (v·|v|²/(|v|² +
    /// tr Σ_v)), so that a velocity the filter barely knows is not extrapolated at full weight.
    void display_pose_at(double t_us, Eigen::Quaterniond& R_body_to_rig, Eigen::Vector3d& t_mm) const;

    /// Body point `b` in the rig frame at the filter's time.
    Eigen::Vector3d to_rig(const Eigen::Vector3d& b_body_mm) const { return R_ * b_body_mm + t_; }

    /// One image of body point `b` in camera `cam`: `px` the observed distorted frame pixel, `shift` a function
    /// (R, t) → normalised-image offset added to the projection (the shaft's occlusion of a marker; may be null).
    /// Returns false (no update) when the point is behind the camera or the innovation fails `nis_gate`.
    /// `nis` receives the normalised innovation squared.
    /// `age_us` > 0: the image was taken that long before the state's time (an out-of-sequence observation: a
    /// low-latency part of a camera whose field began before another camera's part already fused). The state
    /// stays at its time: the image is compared with the pose carried back by the velocities (so it corrects
    /// them too), and the acceleration noise over `age_us` is added to the image's noise.
    template <typename Shift>
    bool update_point(const CameraGeometry& cam, const Eigen::Vector3d& b_body_mm, const Eigen::Vector2d& px,
                      double sigma_x_px, double sigma_y_px, double nis_gate, const Shift& shift, double* nis = nullptr,
                      double age_us = 0.0);

    /// Pulls the body's line through `b_body_mm` along `axis_body` through the rig point `p_rig_mm` (a trocar),
    /// with 1σ `sigma_mm` across the line.
    void update_line_through(const Eigen::Vector3d& b_body_mm, const Eigen::Vector3d& axis_body,
                             const Eigen::Vector3d& p_rig_mm, double sigma_mm);

    /// Predicted pixel of body point `b` in `cam` at the filter's time, or `age_us` before it (false behind the
    /// camera).
    bool predict_pixel(const CameraGeometry& cam, const Eigen::Vector3d& b_body_mm, Eigen::Vector2d& px,
                       double age_us = 0.0) const;

    /// Current time (device µs).
    double time_us() const { return time_us_; }
    /// Orientation body→rig.
    const Eigen::Quaterniond& rotation() const { return R_; }
    /// Translation (mm): the body origin in the rig frame.
    const Eigen::Vector3d& translation() const { return t_; }
    /// Angular velocity (rig frame, rad/s).
    const Eigen::Vector3d& omega() const { return w_; }
    /// Velocity of the body origin (mm/s).
    const Eigen::Vector3d& velocity() const { return v_; }
    /// Angular acceleration (rig frame, rad/s²) and the body origin's (mm/s²): zero in a constant-velocity model.
    const Eigen::Vector3d& angular_acceleration() const { return alpha_; }
    const Eigen::Vector3d& acceleration() const { return acc_; }
    /// Covariance of the error state.
    const Cov& covariance() const { return P_; }
    /// √trace of the position covariance (mm).
    double position_sigma_mm() const { return std::sqrt(std::max(0.0, P_.block<3, 3>(3, 3).trace())); }

    /// update_point in its two halves (BodyFilter shares one linearisation among its models): the predicted pixel
    /// of `b` at the error state `d`, and the Jacobian of that pixel by the error state at d = 0.
    template <typename Shift>
    bool project(const CameraGeometry& cam, const Eigen::Vector3d& b_body_mm, const Shift& shift, double age_us,
                 const State& d, Eigen::Vector2d& px) const;
    template <typename Shift>
    bool linearise(const CameraGeometry& cam, const Eigen::Vector3d& b_body_mm, const Shift& shift, double age_us,
                   Eigen::Vector2d& z0, Jacobian& J) const;
    /// The Kalman update from a predicted pixel z0 and Jacobian J (update_point's second half).
    bool correct(const Eigen::Vector2d& z0, const Jacobian& J, const Eigen::Vector2d& px,
                 double sigma_x_px, double sigma_y_px, double nis_gate, double* nis, double age_us);

    /// Log-likelihood of the last update_point's innovation, −½(min(NIS, gate) + ln det S), or NaN where no
    /// innovation was formed (behind the camera, not finite): what a motion model's probability is updated by.
    double last_log_likelihood() const { return last_log_lik_; }

private:
    friend class BodyFilter;
    void apply(const State& dx);
    /// The motion model over `dt` seconds from the state, with these rates: the pose, and the origin's velocity
    /// at its end (the pivot's velocity plus the turned lever's).
    void propagate(double dt, const Eigen::Vector3d& w, const Eigen::Vector3d& v, const Eigen::Vector3d& alpha,
                   const Eigen::Vector3d& acc, Eigen::Quaterniond& R, Eigen::Vector3d& t, Eigen::Vector3d* v_end) const;
    void roll_pseudo_measurement();
    /// A constant-velocity model's accelerations back to zero with no variance (after the IMM's mixing).
    void clear_acceleration();
    /// correct()'s Kalman update over the leading N error states.
    template <int N>
    bool correct_block(const Jacobian& J, const Eigen::Vector2d& r, const Eigen::Matrix2d& Rn, double nis_gate,
                       double* nis);

    double last_log_lik_ = 0.0;
    bool tracking_ = false;
    bool rotation_only_ = false;
    Eigen::Vector3d roll_axis_body_ = Eigen::Vector3d::Zero();
    double q_ang_ = 1.0, q_lin_ = 1.0;
    bool ca_ = false;
    double qj_ang_ = 0.0, qj_lin_ = 0.0, s_alpha0_ = 0.0, s_acc0_ = 0.0;
    double tau_s_ = 0.0;
    bool pivot_ = false;
    Eigen::Vector3d pivot_body_mm_ = Eigen::Vector3d::Zero(), pivot_axis_body_ = Eigen::Vector3d::UnitZ();
    double pivot_across_ = 1.0;
    double time_us_ = 0.0;
    Eigen::Quaterniond R_ = Eigen::Quaterniond::Identity();
    Eigen::Vector3d t_ = Eigen::Vector3d::Zero(), w_ = Eigen::Vector3d::Zero(), v_ = Eigen::Vector3d::Zero();
    Eigen::Vector3d alpha_ = Eigen::Vector3d::Zero(), acc_ = Eigen::Vector3d::Zero();
    Cov P_ = Cov::Identity();
};

/// One body's estimator in the live chain: up to three RigidBodyFilters of the same body, from a steady motion
/// model (low acceleration noise) to an agile one, mixed as an interacting multiple model (IMM, Blom &
/// Bar-Shalom 1988).
/// Why: one acceleration density is a trade — low, it smooths a held or slowly moved body (the eye at rest, an
/// instrument feeling the retina) but lags a fast turn; high, it follows the turn but passes the centroid noise
/// into the pose. Each image's innovation likelihood under each model moves the model probabilities; the
/// reported state is their mixture. Before each prediction the models' states are mixed by the switching prior,
/// so the steady model never drifts far from a body that moved. With one model it is that model's filter.
class BodyFilter {
public:
    static constexpr int kMaxModels = 4;
    /// `models` motion models (1..kMaxModels), model j with densities ang_psd[j] / lin_psd[j], steadiest first.
    void configure_rigid(const Eigen::Vector3d& roll_axis_body, const double* ang_psd_rad2_s3,
                         const double* lin_psd_mm2_s3, int models, double switch_per_s);
    void configure_rotation(const Eigen::Vector3d& centre_rig_mm, const double* ang_psd_rad2_s3, int models,
                            double switch_per_s);
    /// Model j turns about a pivot (RigidBodyFilter::set_pivot).
    void set_pivot(int model, bool on, const Eigen::Vector3d& pivot_body_mm, const Eigen::Vector3d& axis_body,
                   double across_fraction) {
        if (model >= 0 && model < n_) m_[std::size_t(model)].set_pivot(on, pivot_body_mm, axis_body, across_fraction);
    }
    /// Model j made constant-acceleration (RigidBodyFilter::set_jerk); call after configure_*.
    void set_jerk(int model, double ang_jerk_psd_rad2_s5, double lin_jerk_psd_mm2_s5, double sigma_alpha0_rad_s2,
                  double sigma_acc0_mm_s2, double correlation_s);
    void init(double t_us, const Eigen::Quaterniond& R_body_to_rig, const Eigen::Vector3d& t_mm,
              const Eigen::Vector3d& omega_rad_s, const Eigen::Vector3d& v_mm_s, double sigma_rot_rad,
              double sigma_pos_mm, double sigma_omega_rad_s, double sigma_v_mm_s);
    void reset() {
        for (RigidBodyFilter& m : m_) m.reset();
        dirty_ = true;
    }
    bool tracking() const { return m_[0].tracking(); }
    /// The state (models in use and their probabilities) of `o`, a filter of the same body configured alike: a
    /// snapshot or its restore without copying the unused models and the mixture.
    void assign_state(const BodyFilter& o) {
        for (int j = 0; j < n_; ++j) m_[std::size_t(j)] = o.m_[std::size_t(j)];
        mu_ = o.mu_;
        dirty_ = true;
    }
    /// Mixes the models by the switching prior over the step, then predicts each (RigidBodyFilter::predict_to).
    void predict_to(double t_us);
    /// RigidBodyFilter::update_point on every model (one shared linearisation), then the model probabilities by
    /// each model's innovation likelihood. True when any model took the image; `nis` is the likeliest model's.
    template <typename Shift>
    bool update_point(const CameraGeometry& cam, const Eigen::Vector3d& b_body_mm, const Eigen::Vector2d& px,
                      double sigma_x_px, double sigma_y_px, double nis_gate, const Shift& shift, double* nis = nullptr,
                      double age_us = 0.0);
    /// RigidBodyFilter::update_line_through on every model.
    void update_line_through(const Eigen::Vector3d& b_body_mm, const Eigen::Vector3d& axis_body,
                             const Eigen::Vector3d& p_rig_mm, double sigma_mm);

    // The mixture's estimate (RigidBodyFilter's accessors), formed when first read after a change.
    void pose_at(double t_us, Eigen::Quaterniond& R, Eigen::Vector3d& t) const { mix().pose_at(t_us, R, t); }
    /// Fixed-lag smoothing: the pose at `t_us` given `then`, this filter as it was earlier (its state at a time
    /// near t_us), and everything this one has fused since: one Rauch–Tung–Striebel step over the mixture from
    /// then's time to this one's, x_s = x_then + P_then·Fᵀ·P_pred⁻¹·(x_now − x_pred), x_pred and P_pred then
    /// predicted to now; then the smoothed state carried to t_us. `then` not older than this: pose_at.
    void smoothed_pose_at(const BodyFilter& then, double t_us, Eigen::Quaterniond& R, Eigen::Vector3d& t) const;
    void display_pose_at(double t_us, Eigen::Quaterniond& R, Eigen::Vector3d& t) const {
        mix().display_pose_at(t_us, R, t);
    }
    Eigen::Vector3d to_rig(const Eigen::Vector3d& b_body_mm) const { return mix().to_rig(b_body_mm); }
    bool predict_pixel(const CameraGeometry& cam, const Eigen::Vector3d& b, Eigen::Vector2d& px,
                       double age_us = 0.0) const {
        return mix().predict_pixel(cam, b, px, age_us);
    }
    double time_us() const { return m_[0].time_us(); }
    const Eigen::Quaterniond& rotation() const { return mix().rotation(); }
    const Eigen::Vector3d& translation() const { return mix().translation(); }
    const Eigen::Vector3d& omega() const { return mix().omega(); }
    const Eigen::Vector3d& velocity() const { return mix().velocity(); }
    const RigidBodyFilter::Cov& covariance() const { return mix().covariance(); }
    double position_sigma_mm() const { return mix().position_sigma_mm(); }
    /// Probability of motion model j (0: the steadiest).
    double model_probability(int j) const { return j >= 0 && j < n_ ? mu_[std::size_t(j)] : 0.0; }
    int models() const { return n_; }

private:
    /// Error state of model i relative to model j's (δθ with R_i = exp(δθ)·R_j, then δt, δω, δv).
    static RigidBodyFilter::State difference(const RigidBodyFilter& i, const RigidBodyFilter& j);
    /// `out` = the models' states averaged with weights `w` about model `ref`'s, their covariance widened by the
    /// spread of the means: the IMM's mixing before a prediction and its reported mixture alike.
    void merge(const std::array<double, kMaxModels>& w, int ref, RigidBodyFilter& out) const;
    const RigidBodyFilter& mix() const {
        if (dirty_) combine();
        return n_ == 1 ? m_[0] : c_;
    }
    void combine() const;

    int n_ = 1;
    double switch_per_s_ = 0.0;
    std::array<RigidBodyFilter, kMaxModels> m_{};
    std::array<double, kMaxModels> mu_{1.0, 0.0, 0.0, 0.0};
    mutable RigidBodyFilter c_{};  // the mixture (n_ > 1), formed from the models when dirty_
    mutable bool dirty_ = true;
};

/// Centroid shift (normalised image units, along the projected half-shaft) of a uniform disk of radius `rho`
/// from which a strip of half-width `w`, starting at `t0` from the centre and running to the rim, is hidden (a
/// shaft running through a marker sphere).
double strip_centroid_shift(double rho, double w, double t0);

/// Normalised-image shift of the centroid of the marker at `X_rig_mm` (radius `marker_radius_mm`) on a shaft of
/// radius `shaft_radius_mm` along the unit `axis_rig`, seen by `cam`: what the visible part's centroid moves by.
Eigen::Vector2d shaft_occlusion_shift(const CameraGeometry& cam, const Eigen::Vector3d& X_rig_mm,
                                      const Eigen::Vector3d& axis_rig, double marker_radius_mm,
                                      double shaft_radius_mm);

// ---------------------------------------------------------------------------------------------------------------

namespace detail {
/// Distorted pixel of the normalised point `xn` in `cam`.
Eigen::Vector2d to_pixel(const CameraGeometry& cam, const Eigen::Vector2d& xn);
/// Rotation vector → quaternion.
Eigen::Quaterniond exp_rotation(const Eigen::Vector3d& theta);
}  // namespace detail

template <typename Shift>
bool RigidBodyFilter::project(const CameraGeometry& cam, const Eigen::Vector3d& b, const Shift& shift, double age_us,
                              const State& d, Eigen::Vector2d& out) const {
    // h(δx): projected pixel (plus the occlusion shift) of the perturbed pose, carried back by the age (constant
    // velocity) for an aged image, so that its Jacobian reaches the velocities: δθ − age·δω, δt − age·δv to first
    // order. A current image does not depend on them (zero columns).
    const double a = std::max(0.0, age_us) * 1e-6, h = 0.5 * a * a;
    const Eigen::Vector3d w = w_ + d.segment<3>(6);
    const Eigen::Quaterniond R =
        detail::exp_rotation(-a * w + h * (alpha_ + d.segment<3>(12))) * (detail::exp_rotation(d.head<3>()) * R_);
    Eigen::Vector3d t = t_;
    if (!rotation_only_) t += d.segment<3>(3) - a * (v_ + d.segment<3>(9)) + h * (acc_ + d.segment<3>(15));
    const Eigen::Vector3d X = R * b + t;
    const Eigen::Vector3d Xc = cam.R_cam_rig * X + cam.t_cam_rig_mm;
    if (!(Xc.z() > 1e-6)) return false;
    Eigen::Vector2d xn(Xc.x() / Xc.z(), Xc.y() / Xc.z());
    xn += shift(R, t, X);
    out = detail::to_pixel(cam, xn);
    return out.allFinite();
}

template <typename Shift>
bool RigidBodyFilter::linearise(const CameraGeometry& cam, const Eigen::Vector3d& b, const Shift& shift,
                                double age_us, Eigen::Vector2d& z0, Jacobian& J) const {
    State d = State::Zero();
    if (!project(cam, b, shift, age_us, d, z0)) return false;
    J.setZero();
    // Steps per block (δθ, δt, δω, δv, δα, δa): each moves the pixel by far more than rounding and far less than
    // the projection bends over (the accelerations enter by half the age squared, at most ≈ 1e-4 s²).
    constexpr double kEps[6] = {1e-6, 1e-4, 1e-6, 1e-4, 1e-2, 1.0};
    for (int i = 0; i < kDim; ++i) {  // central differences
        const int block = i / 3;
        if (rotation_only_ && (block & 1)) continue;  // no translation
        if (!(age_us > 0.0) && i >= 6) break;          // a current image does not see the rates
        const double eps = kEps[block];
        Eigen::Vector2d zp, zm;
        d.setZero();
        d[i] = eps;
        if (!project(cam, b, shift, age_us, d, zp)) return false;
        d[i] = -eps;
        if (!project(cam, b, shift, age_us, d, zm)) return false;
        J.col(i) = (zp - zm) / (2.0 * eps);
    }
    return true;
}

template <typename Shift>
bool RigidBodyFilter::update_point(const CameraGeometry& cam, const Eigen::Vector3d& b, const Eigen::Vector2d& px,
                                   double sx, double sy, double nis_gate, const Shift& shift, double* nis,
                                   double age_us) {
    last_log_lik_ = std::numeric_limits<double>::quiet_NaN();
    Eigen::Vector2d z0;
    RigidBodyFilter::Jacobian J;
    if (!linearise(cam, b, shift, age_us, z0, J)) return false;
    return correct(z0, J, px, sx, sy, nis_gate, nis, age_us);
}

template <typename Shift>
bool BodyFilter::update_point(const CameraGeometry& cam, const Eigen::Vector3d& b, const Eigen::Vector2d& px,
                              double sx, double sy, double nis_gate, const Shift& shift_fn, double* nis,
                              double age_us) {
    if (n_ == 1) {
        const bool ok = m_[0].update_point(cam, b, px, sx, sy, nis_gate, shift_fn, nis, age_us);
        dirty_ = true;
        return ok;
    }
    // One linearisation, at the likeliest model's state, serves every model (their states differ by far less
    // than the measurement function bends over); each model predicts its own pixel and takes the image or gates
    // it out on its own innovation.
    int best = 0;
    for (int j = 1; j < n_; ++j)
        if (mu_[std::size_t(j)] > mu_[std::size_t(best)]) best = j;
    RigidBodyFilter::Jacobian J;
    std::array<Eigen::Vector2d, kMaxModels> z;
    if (!m_[std::size_t(best)].linearise(cam, b, shift_fn, age_us, z[std::size_t(best)], J)) return false;
    for (int j = 0; j < n_; ++j)  // every model's pixel before any model changes: all take the image or none
        if (j != best &&
            !m_[std::size_t(j)].project(cam, b, shift_fn, age_us, RigidBodyFilter::State::Zero(), z[std::size_t(j)]))
            return false;
    std::array<double, kMaxModels> q{}, l{};
    bool any = false, all_finite = true;
    double lmax = -std::numeric_limits<double>::infinity();
    for (int j = 0; j < n_; ++j) {
        RigidBodyFilter& m = m_[std::size_t(j)];
        any = m.correct(z[std::size_t(j)], J, px, sx, sy, nis_gate, &q[std::size_t(j)], age_us) || any;
        l[std::size_t(j)] = m.last_log_likelihood();
        all_finite = all_finite && std::isfinite(l[std::size_t(j)]);
        if (all_finite) lmax = std::max(lmax, l[std::size_t(j)]);
    }
    if (all_finite) {
        // μ_j ∝ Λ_j·μ_j, in logs for the tails (a gated image's likelihood is held at the gate's).
        std::array<double, kMaxModels> w{};
        double sum = 0.0;
        for (int j = 0; j < n_; ++j) sum += w[std::size_t(j)] = mu_[std::size_t(j)] * std::exp(l[std::size_t(j)] - lmax);
        if (sum > 0.0 && std::isfinite(sum))
            for (int j = 0; j < n_; ++j) mu_[std::size_t(j)] = std::max(w[std::size_t(j)] / sum, 1e-9);
    }
    if (nis) *nis = q[std::size_t(best)];
    dirty_ = dirty_ || any;
    return any;
}

}  // namespace eyesim::tracking
