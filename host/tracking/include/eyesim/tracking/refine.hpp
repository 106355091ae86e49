/// \file
/// Blob refinement on the host: a least-squares fit of a shaded-sphere marker model (an ellipse
/// in the image, over a background with, where it shows, the eye's limb) to the Y, Cb and Cr samples of a small
/// patch around one blob (docs/tracking.md §"Blob refinement").
///
/// Why: the pipeline's centroid weights come from chroma alone, which 4:2:2 samples once per pixel pair and
/// spreads two columns past the marker; at σ = 1 DN even the best estimator from chroma alone is ≈ 0.017 px off for
/// a 9-px marker (Cramér–Rao bound, docs/bench/fpga-model.md). The luma edge of a shaded sphere (a dark rim against
/// the eye white, at full horizontal resolution) carries most of the position information, but only a model can
/// use it: the luma contrast changes sign with the shading, so no per-pixel weight does.
///
/// The patch is the blob's box with a margin (what a precision-mode camera sends beside the blob); the fit runs on
/// fixed-size storage (no heap, no exceptions in the per-blob path).
#pragma once

#include <array>
#include <span>
#include <cstdint>

namespace eyesim::tracking {

/// A marker class's colour at full shade as offset-free BT.601 studio-swing YCbCr (DN).
struct MarkerColour {
    double y_dn = 0, cb_dn = 0, cr_dn = 0;
    static MarkerColour from_rgb(double r, double g, double b);
};

/// Field lines either side of an observation that the vertical chroma chain reaches (SphereFitConfig::chroma_chain).
inline constexpr int kChromaChainLines = 3;
/// Field lines at each edge whose chain taps the writer's and reader's edge repetition changes (at most three at
/// the top, four at the bottom for the sites below; SphereFitConfig::chroma_v_edge_taps).
inline constexpr int kChromaChainEdgeLines = 4;

/// How the marker's pixels are rendered in the fit.
enum class SphereFitModel : uint8_t {
    kAnalytic,      ///< per pixel: exact coverage of a straight edge through the pixel box, shading in closed form
    kSupersampled,  ///< supersample × supersample points per pixel (slower; the reference)
};

/// What the fit models and when it refuses. The defaults are the rig's shaded spheres; shading 1 / 0 with
/// aperture_lines_px 2 models flat discs whose field pixels integrate a whole field line.
struct SphereFitConfig {
    std::array<MarkerColour, 5> colour{};  ///< per class 1..4 (index 0 unused)
    double shade_ambient = 0.35;           ///< marker shading: ambient + diffuse·cos(angle to the view ray)
    double shade_diffuse = 0.65;
    double noise_dn = 1.0;                 ///< sensor noise σ on Y, Cb, Cr (DN)
    double shot_gain = 0.02;               ///< luma shot-noise variance per DN above black
    SphereFitModel model = SphereFitModel::kAnalytic;
    int supersample = 4;                   ///< kSupersampled: sub-samples per pixel side for coverage and shading
    bool fit_ellipse = true;               ///< fit the outline's ellipticity (pixel aspect, perspective); else a circle
    int max_iterations = 12;
    /// When > 0: the first Gauss–Newton step is taken without a second linearisation to confirm it where the
    /// centre and radius move less than this (px) — a faster, slightly less accurate fit (docs/bench/refine.md,
    /// "The first step unverified"). 0 (the default): every step but a small one after an accepted one is
    /// confirmed.
    double first_step_unverified_px = 0.0;
    double max_reduced_chi2 = 5.0;         ///< a worse fit is refused (another object in the patch, occlusion)
    double outline_step_dn = 40.0;         ///< luma range on the patch border that adds the outline (limb) term
    double max_shift_px = 0.15;            ///< a fit further than this from the pipeline's centroid is refused
    int margin_px = 4;                     ///< patch margin beside the blob's box, columns
    int margin_lines = 2;                  ///< patch margin above and below, field lines
    double max_outlier_fraction = 0.3;     ///< observations a refit may leave out (0: no refit)
    double outlier_sigma = 4.0;            ///< residual (in σ) beyond which an observation is left out
    double max_shift_outliers_px = 0.06;   ///< max_shift_px for a fit that left observations out
    double max_shift_hinted_px = 0.0;      ///< when > 0: max_shift_px for a fit with a MarkerHint
    /// A hinted fit that leaves less than this share of the marker's light visible (a sliver) is anchored by the
    /// pose: its centre may lie near the hint's predicted centre instead of near where the pipeline's centroid
    /// started it, and its centroid must lie within the shift gate, not widened by the hidden share, of the
    /// visible centroid the pose predicts as well as within the widened gate of the pipeline's. 0: never (the
    /// camera's own fields); sphere_fit_config_for_source sets it for lossy and 4:1:1 sources.
    double prediction_gate_visible = 0.0;
    /// A hinted fit refused (χ², implausible, shift) is tried once more from the hint's predicted centre
    /// (MarkerHintSource::fit): on lossy video a partly hidden marker's pipeline centroid can be a pixel or more
    /// off and the fit started behind the occluders from it ends in another minimum. The retry passes the same
    /// gates. sphere_fit_config_for_source sets it for lossy and subsampled sources.
    bool restart_from_prediction = false;
    /// The shift gate's reach in x and in y as multiples of max_shift_px: the pipeline's chroma-only centroid is
    /// that much less certain along a direction in which the source's chroma is coarser than the camera's 4:2:2
    /// (4:1:1: 2 in x; 4:2:0, a chroma line for two field lines: 2 in y).
    double shift_x_scale = 1.0;
    double shift_y_scale = 1.0;
    double aperture_lines_px = 1.0;        ///< a pixel's height in frame px (1: one frame row; 2: a whole field line)
    /// Chroma σ (DN) when > 0, instead of noise_dn: for sources whose chroma is not the sensor's 4:2:2 (subsampled
    /// to 4:2:0 or 4:1:1 and upsampled again, or quantised by a lossy codec), which the model's full-resolution
    /// chroma does not follow; a large σ leaves the position to the luma, full resolution in every format.
    double chroma_noise_dn = 0.0;
    /// Luma σ floor (DN) added in quadrature to the sensor's: a lossy codec's quantisation error.
    double luma_noise_floor_dn = 0.0;
    /// The source's vertical chroma chain (4:2:0 video; chroma_chain_420): on and where the patch with
    /// kChromaChainLines more lines each side fits, each chroma observation at field line y is modelled as
    /// Σ_d chroma_v_taps[parity][y & 1][c][d + kChromaChainLines] · (the camera's 4:2:2 chroma at line y + d), c 0 Cb,
    /// 1 Cr, with σ chain_chroma_noise_dn instead of chroma_noise_dn (which stays for the fits it does not fit).
    bool chroma_chain = false;
    double chroma_v_taps[2][2][2][7] = {};
    /// The chain at the field's edges, where the writer repeats the first (last) field line and the reader the first
    /// (last) chroma row: the taps of field line k (edge 0) and of line chroma_chain_field_lines − 1 − k (edge 1),
    /// k < kChromaChainEdgeLines, [parity][edge][k][c]. With them a marker the image's top or bottom edge cuts is
    /// fitted with its chain too, its patch reaching no line beyond the field. Used on fields of
    /// chroma_chain_field_lines lines only (0: none; the chain then needs kChromaChainLines lines each side).
    double chroma_v_edge_taps[2][2][kChromaChainEdgeLines][2][7] = {};
    int chroma_chain_field_lines = 0;
    /// The same across the columns (4:1:1 video; chroma_chain_411): each chroma observation at the 4:2:2 sample k
    /// (luma column 2k) is Σ_d chroma_h_taps[k & 1][d + kChromaChainLines] · (the camera's chroma sample k + d),
    /// on top of the vertical chain where there is one. The patch then reaches 2·kChromaChainLines columns further.
    /// Fits without a MarkerHint only: an occluder then hides every chroma observation within two samples of it,
    /// and partly hidden markers lost more than the chain gained (FFV1 4:1:1 sweep seed 2: 0.0327 → 0.0376 px).
    bool chroma_chain_h = false;
    double chroma_h_taps[2][7] = {};
    double chain_chroma_noise_dn = 0.0;
    /// Chroma σ (DN) floor of a hinted fit of a marker the eye alone hides part of (a marker on the eye at its
    /// outline: a MarkerHint with an occluding sphere and no shaft): there the chroma misleads the fit more than it
    /// informs it, and the luma decides. Measured, cause not established (docs/validation.md, "Chroma down-weighted
    /// where the eye hides the marker"); 0: the fit's chroma σ as for any other.
    double eye_hidden_chroma_noise_dn = 8.0;
    /// With a MarkerHint: pixels whose box, widened by this much, an occluder's image touches are left out (frame
    /// px). 0: the pixels it touches at all. A margin costs more than it saves: it takes the outline's arcs next to
    /// a shaft, the only ones that place the centre along it (sweep seed 1, instrument markers 5–15 % hidden:
    /// centre 0.016 px RMS at 0, 0.023 at 0.5, 0.048 at 1.5; on DV 0.029 / 0.036 px at 0 / 0.5).
    double occluder_margin_px = 0.0;
    /// Fit a marker with a hint also where the eye's outline crosses its patch (the outline model, p.outline). Off,
    /// such a marker keeps the pipeline's centroid: with a shaft's band out, the outline's model has too little to
    /// stand on (sweep seed 5, raw, instrument markers: 0.078 px RMS against the pipeline's 0.034). On for lossy
    /// sources, whose pipeline centroid is worse still (DV: 0.087 against 0.119).
    bool hint_with_outline = false;
};

/// What the poses predict about one marker's image, for an occlusion-aware fit: its outline, and what hides part
/// of it. An instrument marker is threaded on its shaft, whose axis passes through the marker's centre, so the
/// shaft's image is fixed relative to the fitted sphere by the axis direction alone; a marker on the eye near the
/// eye's outline is partly behind the eye's sphere. The fit leaves out the pixels an occluder covers (with
/// occluder_margin_px), holds the outline to the prediction, and reports the centroid of the part left visible.
/// Where hints come from: the tracker's newest poses (MarkerHintSource, tracking/marker_prediction.hpp).
struct MarkerHint {
    /// Unit shaft direction in the marker's view frame: z along the line of sight from the camera to the marker's
    /// centre, x and y any orthonormal pair across it (the one view_per_px maps to). Sign irrelevant.
    double axis_view[3] = {0, 0, 1};
    double radius_ratio = 0;  ///< shaft radius / marker radius (0: no shaft)
    /// The outline the pose predicts (the fit's r, e1, e2; tracking/marker_prediction.hpp), held by a prior of σ
    /// radius_sigma × r and e_sigma: with an occluder's pixels left out, the outline's remaining arc alone lets the
    /// radius trade against the centre (along a shaft). radius_px 0: no prior.
    double radius_px = 0, e1 = 0, e2 = 0;
    double radius_sigma = 0.01, e_sigma = 0.02;
    /// Row-major 2 × 2 map from a frame-px offset (dx, dv) about the centre to the view frame's (x, y) in marker
    /// radii, at radius_px (the camera's local projection, distortion and pixel aspect included, inverted). All 0:
    /// taken from the fitted outline, which knows the shape but not its rotation.
    double view_per_px[4] = {0, 0, 0, 0};
    /// A sphere that hides part of the marker (the eye, for a marker on its surface near its outline): centre in
    /// the view frame, radius, both in marker radii; the camera at view_distance marker radii along −z (the eye is
    /// too large for the parallel rays the shaft's test takes). occluder_radius 0: none.
    double occluder_view[3] = {0, 0, 0};
    double occluder_radius = 0;
    double view_distance = 0;
    /// The occluding sphere stands still in the image (the eye: its centre is fixed in the rig and a sphere's
    /// outline does not turn with it): occluder_view is about the marker's predicted centre, at (centre_x_px,
    /// centre_v_px) frame px, and moves with the fit's centre by the difference. Otherwise (a neighbour on the same
    /// shaft) it moves with the marker. A pose a field old can be a fraction of a marker off along its motion, which
    /// at the eye's outline is most of the visible part.
    bool occluder_fixed = false;
    double centre_x_px = 0, centre_v_px = 0;
    /// A second occluding sphere, as the first: a marker nearer the camera across this one where the eye is the
    /// first (an eye marker at the outline in front of an instrument marker the eye also hides). occluder2_fixed:
    /// it stays where the image has it (a marker of another body). occluder2_radius 0: none.
    double occluder2_view[3] = {0, 0, 0};
    double occluder2_radius = 0;
    bool occluder2_fixed = false;
};

/// Another instrument's shaft in a blob's patch, as the poses predict its image there: a strip of half-width
/// `half_width_px` about the line through (x_px, v_px) along the unit (ux, uv), from that point on (the tip's end,
/// rounded by the half-width; `from_start` false: unbounded both ways), frame px (v: frame rows). Its pixels are
/// neither the marker nor the background, so the fit leaves them out (MarkerHintSource::patch_mask).
struct ForeignShaft {
    double x_px = 0, v_px = 0, ux = 1, uv = 0, half_width_px = 0;
    bool from_start = false;
};

/// Another marker's image in a blob's patch: a disc about (x_px, v_px) of radius r_px (its predicted outline's,
/// plus a margin), frame px.
struct ForeignDisc {
    double x_px = 0, v_px = 0, r_px = 0;
};

/// What else the poses put in one patch (fixed capacity; counts 0: nothing): other instruments' shafts and other
/// markers, and the marker pixels they must not take: those whose centre lies within keep_radius_px of (keep_x_px,
/// keep_v_px) (the marker's predicted centre; what lies behind it shows only beside it).
struct PatchMask {
    static constexpr int kMaxShafts = 3;
    static constexpr int kMaxDiscs = 4;
    int count = 0;  ///< shafts
    std::array<ForeignShaft, kMaxShafts> shafts{};
    int disc_count = 0;
    std::array<ForeignDisc, kMaxDiscs> discs{};
    double keep_x_px = 0, keep_v_px = 0, keep_radius_px = 0;
    /// The marker's outline as the pose projects it (MarkerHint::radius_px, e1, e2): a merged blob's fit holds its
    /// shape to it.
    double keep_outline_r_px = 0, keep_e1 = 0, keep_e2 = 0;
    /// A marker of the blob's own class lies in its box: the pipeline joined two markers into one blob (their
    /// chroma blurred together, most on lossy video), so its centroid lies between them and no longer anchors the
    /// fit's shift gate; the fitted centre is held to the marker's predicted one (keep_x_px, keep_v_px) instead,
    /// within kMergedMaxShiftPx.
    bool merged = false;
};

/// Whether a pixel box of half-sizes (hx, hv) about (x_px, v_px) (frame px) touches `shaft`'s strip.
bool shaft_touches(const ForeignShaft& shaft, double x_px, double v_px, double hx, double hv);

/// Whether an occluder of `hint` covers the point q of the marker's image, q in units of its radius about its
/// centre (view frame x, y): the shaft's or the occluding sphere's surface there is nearer the camera than the
/// marker's, or the marker is not there.
bool hint_covers(const MarkerHint& hint, double qx, double qy);

/// Where the pipeline's centroid of the marker `hint` predicts lies, less its centre (frame px, v: frame rows), on a
/// field of `parity`: the visible part's intensity centroid (cfg's shading) with the hint's occluders, and that part's
/// share of the marker's light. Needs no pixels: the tracker corrects a partly hidden marker's image by it. False
/// without a usable outline (radius_px, centre) or with nothing visible.
bool hinted_centroid_offset(const SphereFitConfig& cfg, const MarkerHint& hint, int parity, double& dx_px,
                            double& dv_px, double& visible);

/// max_shift_px for a lossy source, whose pipeline centroid is itself ≈ 0.1 px off (the codec's chroma).
inline constexpr double kLossyMaxShiftPx = 0.25;
/// How far a joined blob's fitted centre may lie from the pose's prediction (PatchMask::merged), field px: as far as
/// a lossy source's fit from the pipeline's centroid. The pose is a field or two old.
inline constexpr double kMergedMaxShiftPx = kLossyMaxShiftPx;
/// The same for a merged blob's fit started at the marker's predicted centre with its outline held to the predicted
/// one (fit_sphere's start_at_hint), which does not wander into the neighbour's half as a fit from the blob's moments
/// can: the eye's hint is not moved to the field's time, and on `occlusion` seed 193 (camera 1, two eye markers 6 px
/// apart in one blob on 4:2:0 video) the prediction lay 0.6–0.7 px from such fits within 0.02 px of the truth, which
/// kMergedMaxShiftPx refused. Far short of the neighbour (≥ 4 px). kMergedMaxShiftPx itself at 1.0 px let fits from
/// the moments 0.3–0.6 px off stand (DVCPRO25 `sweep` seed 11, as at 0.5 px before).
inline constexpr double kMergedStartMaxShiftPx = 1.0;
/// max_shift_hinted_px for a lossy source: a partly hidden marker's pipeline centroid is further off still.
inline constexpr double kLossyMaxShiftHintedPx = 0.4;
/// prediction_gate_visible for a lossy source.
inline constexpr double kLossyPredictionGateVisible = 0.5;

/// Chroma and luma σ, and the shift gate, of a fit for a recorded stream: `chroma` "4:2:2", "4:2:0", "4:1:1"
/// (video.hpp VideoInfo), a `lossless` codec or not (a lossy one also widens max_shift_px to kLossyMaxShiftPx and
/// max_shift_hinted_px to kLossyMaxShiftHintedPx, anchors slivers by the pose: prediction_gate_visible, and retries a
/// refused hinted fit from the pose: restart_from_prediction; subsampled chroma stretches the gate along its coarse
/// direction, widens max_shift_hinted_px and retries from the pose too, and 4:1:1 anchors slivers by the pose;
/// either fits hints beside the eye's outline). Raw or lossless 4:2:2 leaves `config` unchanged.
SphereFitConfig sphere_fit_config_for_source(SphereFitConfig config, const char* chroma, bool lossless);

/// Why a fit was refused (the pipeline's centroid then stands).
enum class FitRefusal : uint8_t {
    kNone = 0,     ///< accepted
    kInput,        ///< not a marker class, or an empty blob
    kStorage,      ///< the patch exceeds kFitMaxCols × kFitMaxLines
    kChi2,         ///< reduced χ² above the limit: something else in the patch (a shaft, a neighbour, occlusion)
    kImplausible,  ///< radius, ellipticity, amplitude or centre outside their plausible range, or not finite
    kOutliers,     ///< the observations left out do not lie on a band through the marker (not a shaft)
    kShift,        ///< the fitted centroid is further than max_shift_px (max_shift_outliers_px) from the pipeline's
    kHintOutline,  ///< a hint and the eye's outline in one patch, where hint_with_outline is off
};

/// Number of FitRefusal values (for tallies indexed by them).
inline constexpr int kFitRefusalCount = static_cast<int>(FitRefusal::kHintOutline) + 1;

/// One word for a refusal, for CSV and reports.
const char* to_string(FitRefusal r);

struct SphereFitResult {
    bool ok = false;              ///< false: keep the pipeline's centroid
    FitRefusal refusal = FitRefusal::kInput;
    double cx_px = 0, cy_px = 0;  ///< intensity centroid of the fitted marker (field px, the pipeline's frame)
    double centre_x_px = 0;       ///< fitted sphere centre (field px)
    double centre_y_px = 0;
    double radius_px = 0;         ///< fitted radius in frame px (a field line is two frame px tall)
    double e1 = 0, e2 = 0;        ///< fitted ellipticity: outline (1 + e1)·dx² + 2·e2·dx·dv + (1 − e1)·dv² = r²
    double reduced_chi2 = 0;      ///< residual Σ(r/σ)² per degree of freedom
    bool outline = false;         ///< the background model had a step (eye outline, shaft edge)
    int iterations = 0;
    int outliers = 0;             ///< observations left out of the final fit
    bool outlier_band = false;    ///< they lie on a band through the marker (a shaft), the only case accepted
    bool hinted = false;          ///< a MarkerHint was modelled: cx/cy_px are the visible part's centroid
    int hidden_pixels = 0;        ///< luma observations the hint's occluders left out
};

/// A field's width in pixels (UYVY, 720 × its lines).
inline constexpr int kImageColumns = 720;

/// Largest patch the fit accepts: wider or taller blobs keep the pipeline's centroid.
inline constexpr int kFitMaxCols = 40;
inline constexpr int kFitMaxLines = 18;

/// Working storage for one fit (about 250 KiB; allocate once, reuse).
struct SphereFitWorkspace {
    static constexpr int kCols = kFitMaxCols + 2, kLines = kFitMaxLines;
    static constexpr int kPx = kCols * kLines;
    std::array<double, kPx> cov{}, shade{};        // marker coverage and coverage × shading per pixel
    std::array<double, kPx * 5> dcov{}, dshade{};  // their derivatives by centre x, centre v, radius, e1, e2
    std::array<double, kPx * 2> trial{};           // coverage and shading at a trial point
    std::array<double, kPx * 3> val{};             // model pixels (Y, Cb, Cr)
    std::array<double, kPx> edge_w{};              // weight of the background inside the outline
    std::array<double, kPx> edge_p{}, edge_dp{};   // limb profile P(s) and dP/ds
    std::array<double, kPx> edge_dphi{}, edge_dkappa{};  // ∂dist/∂φ, ∂dist/∂κ
    std::array<uint8_t, kPx> keep_y{}, keep_cb{}, keep_cr{};  // 1: the observation is in the fit
    std::array<uint8_t, kPx> touch{};              // 1: the marker (or its derivatives) reaches the model pixel
    std::array<uint8_t, kPx> hidden_y{}, hidden_c{};  // 1: a MarkerHint's shaft covers the luma / chroma observation
    std::array<uint8_t, kPx> foreign_y{}, foreign_c{};  // 1: a PatchMask's foreign shaft touches it
    std::array<double, kPx> obs_y{}, var_y{};
    std::array<double, kPx> obs_cb{}, obs_cr{};    // chroma samples (even columns)
    // The vertical chroma chain (SphereFitConfig::chroma_chain): per chroma channel, line and sample the [1 2 1]
    // filtered model value and its row of derivatives by the channel's 14 compact parameters.
    static constexpr int kSamples = kCols / 2 + 1, kChainRow = 14;
    std::array<double, 2 * kLines * kSamples * kChainRow> chain_row{};
    std::array<double, 2 * kLines * kSamples> chain_val{};
};

/// What the fit needs of a pipeline blob: its class, field parity, box and centroid (field px).
struct BlobBox {
    int class_id = 0;                        ///< colour class 1..4
    int parity = 0;                          ///< field parity (0 top, 1 bottom)
    int x_min = 0, x_max = -1;               ///< bounding box, inclusive columns
    int y_min = 0, y_max = -1;               ///< bounding box, inclusive field lines
    double cx_px = 0, cy_px = 0;             ///< the pipeline's centroid (field px)
    /// Another class's blob box overlaps this one's (mark_foreign_overlaps): that marker's chroma, spread across
    /// the border between them (most on subsampled video), took or added pixels to the pipeline's blob, whose
    /// centroid and moments are then off by more (sweep seed 6, 4:1:1: an eye marker across a light-pipe marker,
    /// 0.7 and 2.3 px). The fit's shift gate is kForeignOverlapGateScale wider, and a hinted fit's centre may be
    /// near the pose's prediction instead of near where the moments started it.
    bool foreign_overlap = false;
    /// Another class's blob box touches this one's, with no column or line between them (mark_foreign_overlaps):
    /// the chroma filtered across the border (4:2:0 video: over a field line) mixes them, and the pipeline's centroid
    /// moves by tenths of a pixel (sweep seed 25, H.264: an eye marker 3.5 px below a light-pipe marker, 0.4 px). A
    /// plain fit's shift gate is kForeignOverlapGateScale wider; a hinted one's, already wide for the hidden share,
    /// is not (widened, it took a marker two thirds hidden 2.9 px off: sweep seed 14, MPEG-2).
    bool foreign_touch = false;
};

/// The shift gate's factor for a blob with BlobBox::foreign_overlap.
inline constexpr double kForeignOverlapGateScale = 2.0;

/// The BlobBox of any blob type with the pipeline blob's fields (fpga::Blob).
template <class B>
BlobBox blob_box(const B& b) {
    return {b.class_id, b.parity & 1, b.x_min, b.x_max, b.y_min, b.y_max, b.cx_px(), b.cy_px(), false, false};
}

/// chain_chroma_noise_dn for a lossy 4:2:0 source: the chain is modelled, the codec's quantisation of the chroma
/// is not (`sweep` seeds 1–10, 2 s: DV, MPEG-2 and H.264 best at 3–4 DN; lossless FFV1 4:2:0 at the sensor's 1 DN).
inline constexpr double kLossyChainChromaNoiseDn = 4.0;

/// Sets config's vertical chroma chain for interlaced 4:2:0 video: per field, chroma row k of component c (0 Cb,
/// 1 Cr) is sited at field line 2k + site_lines[parity][c] and holds the 2:1 decimation tent (half-width two field
/// lines) centred there; the reader gives field line y the linear interpolation between the two rows about it
/// (rig/video.hpp field_chroma_site). MPEG-2 and H.264 sites: 0.25 (top field) and 0.75 (bottom); DV's
/// line-alternate 4:2:0: Cr 0, Cb 1. Also sets chroma_chain and, where it was 0, chain_chroma_noise_dn to the sensor's,
/// and the taps at the edges of a field of `field_lines` lines (both edges repeated, as rig::VideoWriter and
/// rig::VideoReader do; 0: none).
void chroma_chain_420(SphereFitConfig& config, const double site_lines[2][2], int field_lines = 0);

/// The vertical chain's taps for the chroma of component c (0 Cb, 1 Cr) on field line y of a field of `parity` and
/// `field_lines` lines, over the lines y + d, d = −kChromaChainLines … kChromaChainLines (index d +
/// kChromaChainLines): the edge taps within kChromaChainEdgeLines of either edge where config has them for that
/// height, the interior ones elsewhere.
const double* chroma_chain_v_taps(const SphereFitConfig& config, int parity, int y, int c, int field_lines);

/// Sets config's horizontal chroma chain for 4:1:1 video: 4:1:1 sample m is sited at luma column 4m + site_px and
/// holds the [1 2 1]/4 decimation (the tent of half-width two 4:2:2 samples) about it; the reader gives each 4:2:2
/// sample the linear interpolation between the two 4:1:1 samples about it (rig/video.hpp chroma_column_site). DV's
/// (DVCPRO25) site: 0. Also sets chroma_chain_h and, where it was 0, chain_chroma_noise_dn to the sensor's.
void chroma_chain_411(SphereFitConfig& config, double site_px);

/// Whether the boxes of `a` and `b` come within `gap` columns and lines of each other (0: they overlap).
inline bool boxes_within(const BlobBox& a, const BlobBox& b, int gap) {
    return a.x_min <= b.x_max + gap && b.x_min <= a.x_max + gap && a.y_min <= b.y_max + gap && b.y_min <= a.y_max + gap;
}

/// Whether `a` and `b` are of different classes and their boxes overlap (BlobBox::foreign_overlap).
inline bool foreign_overlap(const BlobBox& a, const BlobBox& b) { return a.class_id != b.class_id && boxes_within(a, b, 0); }

/// Whether `a` and `b` are of different classes and their boxes touch without overlapping: no column or line
/// between them (BlobBox::foreign_touch).
inline bool foreign_touch(const BlobBox& a, const BlobBox& b) {
    return a.class_id != b.class_id && boxes_within(a, b, 1) && !boxes_within(a, b, 0);
}

/// Sets BlobBox::foreign_overlap and foreign_touch of each of `boxes` (one field's blobs): whether another class's
/// box overlaps it, or touches it.
void mark_foreign_overlaps(std::span<BlobBox> boxes);

/// Fits the blob's marker in `field` (UYVY, 720 × `height` lines). The field must hold the blob's lines and
/// `margin_lines` more either side where the image has them.
/// With `shaft`, the shaft's pixels are left out and cx/cy_px are the centroid of the sphere's part the shaft leaves
/// visible (the pipeline's centroid measures that part too). With `mask`, the pixels its foreign shafts touch are
/// left out (from the observations and from the border's levels and outline search). `start_at_hint`: with a hint,
/// the fit starts at the hint's predicted centre instead of behind the occluders from the pipeline's centroid; with
/// a merged `mask` and no hint, at the marker's predicted centre with its outline held to the predicted one
/// (PatchMask::keep_outline_r_px). Its gates are the same but the merged blob's (kMergedStartMaxShiftPx).
SphereFitResult fit_sphere(const uint8_t* field, int height, const BlobBox& blob, const SphereFitConfig& config,
                           SphereFitWorkspace& work, const MarkerHint* hint = nullptr, const PatchMask* mask = nullptr,
                           bool start_at_hint = false);

}  // namespace eyesim::tracking
