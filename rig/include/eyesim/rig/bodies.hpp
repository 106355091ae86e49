#pragma once
/// \file
/// Rigid marker bodies of the rig (scenes/bodies.json): the mechanical eye and the instrument kinds. The
/// synthesiser renders from this file and the tracker fits poses to the SAME file.
///
/// Frames
/// - Eye frame (mm): origin at the eye centre, axes equal to the rig axes when the eye is at rest. The eye
///   rotates about its centre; `q_eye_to_rig` maps eye-frame vectors to the rig frame.
/// - Instrument frame (mm): origin at the instrument TIP, +z along the shaft axis from the tip towards the
///   handle. Markers are spheres centred ON the axis at z = distance_from_tip_mm.
///
/// Identification: eye markers are all class 4 (yellow) and lie on the eye sphere (radius_mm + marker radius
/// from the centre); each instrument kind carries three class 1..3 markers whose colour order from the tip is
/// a distinct permutation of (red, green, blue), with unequal spacings (5 mm then 7 mm) giving the direction.
/// Colour classes: 1 red (220,40,40), 2 green (40,200,60), 3 blue (40,80,220), 4 yellow (230,210,40), sRGB as lit.

#include <Eigen/Core>

#include <array>
#include <cstdint>
#include <string>
#include <vector>

namespace eyesim::rig {

/// Instrument kinds of the simulator.
enum class InstrumentKind : uint8_t { kPick = 0, kForceps = 1, kVitrector = 2, kLightPipe = 3, kInjection = 4 };

/// Name used in bodies.json and truth.jsonl: "pick", "forceps", "vitrector", "light_pipe", "injection".
const char* instrument_kind_name(InstrumentKind kind) noexcept;

/// sRGB colour (as lit, fully facing the light) of colour class 1..4.
std::array<uint8_t, 3> marker_class_rgb(int colour_class);

/// One marker of the eye.
struct EyeMarker {
    int id = 0;                        ///< index within the eye
    int colour_class = 4;              ///< 1..4
    Eigen::Vector3d position_eye_mm;   ///< sphere centre in the eye frame
    double radius_mm = 0.6;            ///< marker sphere radius
};

/// One trocar hole on the eye surface.
struct Trocar {
    int id = 0;                        ///< 0 = tissue-instrument trocar, 1 = light-pipe trocar
    Eigen::Vector3d position_eye_mm;   ///< hole centre on the eye surface, eye frame
};

/// The mechanical eye.
struct EyeBody {
    Eigen::Vector3d center_rig_mm = Eigen::Vector3d::Zero();  ///< rotation centre in the rig frame
    double radius_mm = 12.0;                                  ///< sphere radius
    std::vector<EyeMarker> markers;                           ///< on the visible (lower) surface
    std::vector<Trocar> trocars;                              ///< two holes on the upper hemisphere
};

/// One marker of an instrument (a sphere threaded on the shaft).
struct InstrumentMarker {
    int id = 0;                        ///< index from the tip (0 = nearest the tip)
    int colour_class = 1;              ///< 1..4
    double distance_from_tip_mm = 0;   ///< along the shaft axis
    double radius_mm = 0.6;            ///< marker sphere radius
};

/// One instrument kind.
struct InstrumentBody {
    InstrumentKind kind = InstrumentKind::kPick;
    std::string name;                  ///< instrument_kind_name(kind)
    double shaft_radius_mm = 0.25;     ///< 25 G shaft
    double shaft_length_mm = 60.0;     ///< from the tip to the handle end of the rendered shaft
    double tip_offset_mm = 0.0;        ///< tip lies this far beyond the shaft's distal end (forceps jaws)
    double max_insertion_mm = 22.0;    ///< deepest tip position behind the trocar along the axis
    std::vector<InstrumentMarker> markers;  ///< ordered from the tip

    /// Marker centre in the instrument frame.
    Eigen::Vector3d marker_position_mm(size_t i) const { return {0.0, 0.0, markers.at(i).distance_from_tip_mm}; }
};

/// One marker of the calibration wand (a sphere on the wand's rod).
struct WandMarker {
    int id = 0;                        ///< index along the rod (0 = the end marker, distance 0)
    int colour_class = 2;              ///< 1..4
    double distance_mm = 0;            ///< along the rod from marker 0
    double radius_mm = 0.6;            ///< marker sphere radius
};

/// The calibration wand: a thin rod carrying collinear markers at known, unequal spacings (so the two ends are
/// told apart in every view). Wand frame (mm): origin at marker 0's centre, +z along the rod towards the last
/// marker. The rod itself is thin and dark: it is not drawn (it would only occlude marker edges).
struct WandBody {
    std::vector<WandMarker> markers;   ///< ordered along the rod; empty when bodies.json has no wand

    /// Whether bodies.json describes a wand.
    bool present() const noexcept { return !markers.empty(); }
    /// Marker centre in the wand frame.
    Eigen::Vector3d marker_position_mm(size_t i) const { return {0.0, 0.0, markers.at(i).distance_mm}; }
    /// Distance from the first to the last marker centre.
    double length_mm() const noexcept { return markers.empty() ? 0.0 : markers.back().distance_mm; }
};

/// Everything in bodies.json.
struct Bodies {
    EyeBody eye;                             ///< the mechanical eye
    std::vector<InstrumentBody> instruments; ///< one entry per kind
    WandBody wand;                           ///< the calibration wand (optional in the file)

    /// The body of `kind`; throws std::out_of_range if the file lacks it.
    const InstrumentBody& instrument(InstrumentKind kind) const;
};

/// Reads bodies.json. Throws RigError "<path>: <json pointer>: <why>" on missing keys, wrong types, NaN,
/// colour classes outside 1..4, or an unknown instrument kind. The "wand" entry is optional; when present it
/// needs at least 2 markers, the first at distance 0 and distances strictly increasing.
Bodies load_bodies(const std::string& path);

/// Path of the project's scenes/bodies.json (compiled-in source path), for tools and tests.
std::string default_bodies_path();

}  // namespace eyesim::rig
