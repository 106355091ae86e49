// Stereo scene renderer: pictures that look like the microscope view, checked against the view geometry and the
// light pipe's shadow geometry computed here independently (pinhole projection, ray-sphere intersection).
#include "eyesim/render/egl_context.hpp"
#include "eyesim/render/scene_instruments.hpp"
#include "eyesim/render/scene_renderer.hpp"
#include "eyesim/sim/collision/instrument.hpp"
#include "eyesim/sim/mesh.hpp"

#include <catch2/catch.hpp>
#include <opencv2/imgcodecs.hpp>

#include <Eigen/Geometry>

#include <cmath>
#include <cstdio>
#include <cstring>
#include <optional>
#include <string>
#include <vector>

namespace {

using eyesim::render::InstrumentView;
using eyesim::render::MeshView;
using eyesim::render::RenderConfig;
using eyesim::render::SceneFrame;
using eyesim::render::SceneRenderer;
using eyesim::render::StereoImages;
using Eigen::Vector3f;
namespace col = eyesim::sim::collision;

constexpr int kW = 640, kH = 480;
constexpr float kEyeR = 12.0f;

/// One renderer per test process (creating EGL contexts repeatedly is slow on llvmpipe). Skips (null, with a
/// message) only when no EGL / GLES 3 context can be made at all; any other failure of the renderer fails.
SceneRenderer* renderer() {
    static std::string error;
    static std::unique_ptr<SceneRenderer> r = SceneRenderer::create(kW, kH, error);
    if (!r) {
        std::string egl_error;
        const bool egl_works = eyesim::render::EglContext::create(egl_error) != nullptr;
        if (egl_works) FAIL("EGL works but the scene renderer failed: " << error);
        WARN("SKIPPED: no headless EGL / GLES 3 here: " << error);
    }
    return r.get();
}

std::string out_path(const std::string& name) { return std::string(EYESIM_TEST_OUT) + "/" + name; }

/// Pinhole projection of the documented microscope geometry, written independently of the renderer:
/// returns the pixel (column, row) whose centre the point projects onto; rows count from the top.
Eigen::Vector2f project(const RenderConfig& c, int view, const Vector3f& p) {
    const float half = c.stereo_angle_deg * 0.5f * float(M_PI) / 180.0f * (view == 0 ? -1.0f : 1.0f);
    const Vector3f cam = c.focus_eye_mm + c.view_distance_mm * Vector3f(std::sin(half), 0, std::cos(half));
    const Vector3f f = (c.focus_eye_mm - cam).normalized();
    const Vector3f right = f.cross(Vector3f::UnitY()).normalized();
    const Vector3f up = right.cross(f);
    const Vector3f d = p - cam;
    const float focal_px = 0.5f * kH / std::tan(0.5f * c.vertical_fov_deg * float(M_PI) / 180.0f);
    const float u = 0.5f * kW + focal_px * d.dot(right) / d.dot(f);
    const float v = 0.5f * kH - focal_px * d.dot(up) / d.dot(f);
    return {u - 0.5f, v - 0.5f};
}

Vector3f view_position(const RenderConfig& c, int view) {
    const float half = c.stereo_angle_deg * 0.5f * float(M_PI) / 180.0f * (view == 0 ? -1.0f : 1.0f);
    return c.focus_eye_mm + c.view_distance_mm * Vector3f(std::sin(half), 0, std::cos(half));
}

/// Far intersection of the ray o + t·d (t > 0) with the eye sphere: where a ray from inside meets the wall.
std::optional<Vector3f> hit_wall(const Vector3f& o, const Vector3f& dir) {
    const Vector3f d = dir.normalized();
    const float b = o.dot(d), cc = o.squaredNorm() - kEyeR * kEyeR;
    const float disc = b * b - cc;
    if (disc < 0) return std::nullopt;
    const float t = -b + std::sqrt(disc);
    if (t <= 0) return std::nullopt;
    return o + t * d;
}

/// Distance from point p to segment [a, b].
float segment_distance(const Vector3f& p, const Vector3f& a, const Vector3f& b) {
    const Vector3f ab = b - a;
    const float t = std::clamp((p - a).dot(ab) / ab.squaredNorm(), 0.0f, 1.0f);
    return (a + t * ab - p).norm();
}

/// Distance between the segments [p0, p1] and [q0, q1], by dense sampling (test-side, no cleverness needed).
float segments_distance(const Vector3f& p0, const Vector3f& p1, const Vector3f& q0, const Vector3f& q1) {
    float best = 1e9f;
    for (int i = 0; i <= 400; ++i) best = std::min(best, segment_distance(p0 + (p1 - p0) * (i / 400.0f), q0, q1));
    return best;
}

/// Mean luminance (Rec. 601 on the 8-bit values) in a (2r+1)² window around pixel (u, v).
double luminance(const std::vector<uint8_t>& rgba, Eigen::Vector2f px, int r = 1) {
    const int cu = int(std::lround(px.x())), cv = int(std::lround(px.y()));
    double sum = 0;
    int n = 0;
    for (int y = cv - r; y <= cv + r; ++y)
        for (int x = cu - r; x <= cu + r; ++x) {
            if (x < 0 || y < 0 || x >= kW || y >= kH) continue;
            const uint8_t* p = &rgba[(size_t(y) * kW + x) * 4];
            sum += 0.299 * p[0] + 0.587 * p[1] + 0.114 * p[2];
            ++n;
        }
    return n ? sum / n : 0.0;
}

/// An instrument posed in the eye frame: tip at `tip`, pointing along `forward`.
struct Posed {
    col::Instrument shape;
    std::vector<Vector3f> vertices;
    Vector3f tip, forward;
    Posed(col::Instrument s, const Vector3f& tip_eye, const Vector3f& forward_eye)
        : shape(std::move(s)), tip(tip_eye), forward(forward_eye.normalized()) {
        // The procedural shafts are 12 mm long; stretch them to 24 mm so that they reach the trocars.
        for (Vector3f& v : shape.mesh.vertices_mm)
            if (v.z() < -2.0f) v.z() = -2.0f + (v.z() + 2.0f) * (22.0f / 10.0f);
        Eigen::Matrix3f rot;
        const Vector3f x = forward.cross(Vector3f::UnitY()).normalized();
        rot.col(0) = x;
        rot.col(1) = forward.cross(x);
        rot.col(2) = forward;
        for (const Vector3f& v : shape.mesh.vertices_mm) vertices.push_back(tip + rot * v);
    }
    InstrumentView view(bool light_pipe) const {
        return {MeshView{vertices, shape.mesh.triangles}, tip, forward, light_pipe};
    }
    /// Back end of the shaft (24 mm behind the tip).
    Vector3f back() const { return tip - 24.0f * forward; }
};

/// The test scene: a membrane over the posterior pole, forceps from the right trocar, a light pipe from below.
struct Scene {
    eyesim::sim::TriangleMesh membrane = eyesim::sim::make_membrane_patch(5.0f, 5.0f, 22, 23);
    Vector3f membrane_centre{-1.5f, 1.5f, -10.6f};
    Posed forceps{col::make_forceps(), Vector3f(2.0f, -0.5f, -8.0f),
                  Vector3f(2.0f, -0.5f, -8.0f) - Vector3f(8.5f, 0.0f, 8.5f)};
    Posed light{col::make_light_pipe(), Vector3f(-1.0f, -5.5f, -3.0f),
                Vector3f(0.5f, 1.0f, -12.0f) - Vector3f(-1.0f, -5.5f, -3.0f)};
    std::vector<InstrumentView> instruments;
    Scene() {
        for (Vector3f& v : membrane.vertices_mm) v += membrane_centre;
    }
    /// Moves the light pipe (tip, and the point it aims at).
    void aim_light(const Vector3f& tip, const Vector3f& target) { light = Posed(col::make_light_pipe(), tip, target - tip); }
    SceneFrame frame(bool with_membrane, bool with_forceps, bool with_light) {
        instruments.clear();
        if (with_forceps) instruments.push_back(forceps.view(false));
        if (with_light) instruments.push_back(light.view(true));
        SceneFrame f;
        f.eye_radius_mm = kEyeR;
        if (with_membrane) f.tissue = MeshView{membrane.vertices_mm, membrane.triangles};
        f.instruments = instruments;
        return f;
    }
    /// Whether the camera ray of `view` to `p` crosses the membrane (its plane inside the patch, plus a margin).
    bool behind_membrane(const RenderConfig& c, int view, const Vector3f& p, float margin_mm) const {
        const Vector3f cam = view_position(c, view);
        const float t = (membrane_centre.z() - cam.z()) / (p.z() - cam.z());
        if (t <= 0 || t >= 1) return false;
        const Vector3f q = cam + t * (p - cam);
        return std::abs(q.x() - membrane_centre.x()) < 2.5f + margin_mm &&
               std::abs(q.y() - membrane_centre.y()) < 2.5f + margin_mm;
    }
};

bool write_views(const std::string& name, const StereoImages& img) {
    std::string error;
    const bool ok = eyesim::render::write_side_by_side_png(out_path(name), img, error);
    if (!ok) WARN(error);
    return ok;
}

}  // namespace

TEST_CASE("scene renderer: the microscope view shows a lit fundus, membrane and instruments", "[render][scene]") {
    SceneRenderer* r = renderer();
    if (!r) return;
    INFO("renderer: " << r->renderer_name());
    Scene s;
    StereoImages img;
    r->render(s.frame(true, true, true), img);
    REQUIRE(img.width == kW);
    REQUIRE(img.height == kH);
    REQUIRE(img.left_rgba.size() == size_t(kW) * kH * 4);
    CHECK(write_views("scene_full.png", img));

    // Not uniform: a wide spread of luminance.
    double sum = 0, sum2 = 0;
    for (size_t i = 0; i < img.left_rgba.size(); i += 4) {
        const double l = 0.299 * img.left_rgba[i] + 0.587 * img.left_rgba[i + 1] + 0.114 * img.left_rgba[i + 2];
        sum += l;
        sum2 += l * l;
    }
    const double n = double(kW) * kH, mean = sum / n, sd = std::sqrt(sum2 / n - mean * mean);
    CHECK(sd > 20.0);
    // Outside the round field stop: black.
    for (const auto& px : {Eigen::Vector2f(2, 2), Eigen::Vector2f(kW - 3, 2), Eigen::Vector2f(2, kH - 3)})
        CHECK(luminance(img.left_rgba, px) < 1.0);
    // The retina in the light pipe's spot, away from membrane and instruments: lit and red-orange.
    const Eigen::Vector2f fundus_px = project(r->config(), 0, Vector3f(2.0f, 3.5f, -std::sqrt(144.0f - 16.25f)));
    const uint8_t* p = &img.left_rgba[(size_t(std::lround(fundus_px.y())) * kW + size_t(std::lround(fundus_px.x()))) * 4];
    INFO("fundus pixel " << int(p[0]) << " " << int(p[1]) << " " << int(p[2]));
    CHECK(p[0] > 120);
    CHECK(p[0] > p[1] + 50);
    CHECK(p[1] >= p[2]);
    // The forceps tip: grey metal (channels close together), distinct from the red fundus.
    const Eigen::Vector2f tip_px = project(r->config(), 0, s.forceps.tip - 0.4f * s.forceps.forward);
    const uint8_t* t = &img.left_rgba[(size_t(std::lround(tip_px.y())) * kW + size_t(std::lround(tip_px.x()))) * 4];
    INFO("forceps pixel " << int(t[0]) << " " << int(t[1]) << " " << int(t[2]));
    CHECK(std::abs(int(t[0]) - int(t[2])) < 40);
    // The membrane: greyer (less saturated) than the same retina without it, seen where it is not shadowed.
    StereoImages bare;
    r->render(s.frame(false, true, true), bare);
    const Eigen::Vector2f mem_px = project(r->config(), 0, s.membrane_centre + Vector3f(-1.0f, 1.0f, 0.0f));
    auto sat = [&](const std::vector<uint8_t>& im) {
        const uint8_t* q = &im[(size_t(std::lround(mem_px.y())) * kW + size_t(std::lround(mem_px.x()))) * 4];
        return double(q[0]) - double(q[2]);
    };
    CHECK(sat(img.left_rgba) < 0.85 * sat(bare.left_rgba));
}

TEST_CASE("scene renderer: left and right views differ by the stereo disparity of the geometry", "[render][scene]") {
    SceneRenderer* r = renderer();
    if (!r) return;
    const RenderConfig& c = r->config();
    // Dots at several depths: near the focus (≈ zero disparity) and closer to the microscope (crossed).
    const Vector3f points[] = {{0.5f, -0.8f, -10.5f}, {1.5f, -1.0f, -6.5f}, {-2.0f, 1.5f, -3.0f}, {3.0f, 2.0f, -8.0f}};
    for (const Vector3f& pt : points) {
        const Vector3f dots[] = {pt};
        SceneFrame f;
        f.highlight_nodes_eye_mm = dots;
        StereoImages img;
        r->render(f, img);
        Eigen::Vector2f measured[2];
        for (int view = 0; view < 2; ++view) {
            const auto& im = view == 0 ? img.left_rgba : img.right_rgba;
            double sx = 0, sy = 0, sw = 0;
            for (int y = 0; y < kH; ++y)
                for (int x = 0; x < kW; ++x) {
                    const uint8_t* q = &im[(size_t(y) * kW + x) * 4];
                    const double w = double(q[1]) - double(q[0]);  // the dot is green, the fundus red
                    if (w > 60) {
                        sx += w * x;
                        sy += w * y;
                        sw += w;
                    }
                }
            REQUIRE(sw > 0);
            measured[view] = Eigen::Vector2f(float(sx / sw), float(sy / sw));
        }
        const Eigen::Vector2f pl = project(c, 0, pt), pr = project(c, 1, pt);
        INFO("point " << pt.transpose() << " predicted L " << pl.transpose() << " R " << pr.transpose()
                      << " measured L " << measured[0].transpose() << " R " << measured[1].transpose());
        CHECK((measured[0] - pl).norm() < 1.0f);
        CHECK((measured[1] - pr).norm() < 1.0f);
        const float disparity = measured[0].x() - measured[1].x(), predicted = pl.x() - pr.x();
        CHECK(std::abs(disparity - predicted) < 0.5f);
        if (pt.z() > -7.0f) CHECK(std::abs(predicted) > 5.0f);  // the check has teeth: real depth separation
    }
}

namespace {

/// Renders `s` with and without its forceps and compares retina pixels on rays from the light: through the forceps
/// axis (must be in shadow) and 1.2 mm beside the shaft (must be unchanged). Points the forceps or the membrane
/// hide from a view, or outside the inner spot cone, are skipped.
struct ShadowCounts {
    int shadow_n = 0, shadow_dark = 0, control_n = 0, control_same = 0;
};

ShadowCounts forceps_shadow(SceneRenderer& r, Scene& s, const char* png) {
    const RenderConfig& c = r.config();
    StereoImages with, without;
    r.render(s.frame(true, true, true), with);
    r.render(s.frame(true, false, true), without);
    if (png) {
        CHECK(write_views(std::string(png) + "_with_forceps.png", with));
        CHECK(write_views(std::string(png) + "_without_forceps.png", without));
    }
    ShadowCounts n;
    for (int view = 0; view < 2; ++view) {
        const auto& a = view == 0 ? with.left_rgba : with.right_rgba;
        const auto& b = view == 0 ? without.left_rgba : without.right_rgba;
        for (float back = 0.3f; back < 12.0f; back += 0.1f) {
            const Vector3f q = s.forceps.tip - back * s.forceps.forward;
            const Vector3f ray = q - s.light.tip;
            if (ray.normalized().dot(s.light.forward) < std::cos(27.0f * float(M_PI) / 180.0f)) continue;
            const Vector3f side = ray.cross(s.forceps.forward).normalized();
            for (int k = 0; k < 3; ++k) {
                const Vector3f through = k == 0 ? q : q + (k == 1 ? 1.2f : -1.2f) * side;
                const auto wall = hit_wall(s.light.tip, through - s.light.tip);
                if (!wall) continue;
                const Vector3f cam = view_position(c, view);
                if (segments_distance(cam, *wall, s.forceps.tip, s.forceps.back()) < 0.8f) continue;
                if (s.behind_membrane(c, view, *wall, 0.3f)) continue;
                const Eigen::Vector2f px = project(c, view, *wall);
                if ((px - Eigen::Vector2f(kW / 2.0f, kH / 2.0f)).norm() > 0.9f * kH / 2) continue;
                const double la = luminance(a, px), lb = luminance(b, px);
                if (k == 0) {
                    ++n.shadow_n;
                    n.shadow_dark += la < 0.6 * lb;
                    UNSCOPED_INFO("shadow px " << px.transpose() << ": " << la << " vs " << lb);
                } else {
                    ++n.control_n;
                    n.control_same += std::abs(la - lb) < 0.08 * lb + 2.0;
                    UNSCOPED_INFO("control px " << px.transpose() << ": " << la << " vs " << lb);
                }
            }
        }
    }
    return n;
}

}  // namespace

TEST_CASE("scene renderer: the forceps cast the light pipe's shadow where projection from the light predicts",
          "[render][scene]") {
    SceneRenderer* r = renderer();
    if (!r) return;
    Scene s;
    const ShadowCounts n = forceps_shadow(*r, s, "scene_shadow");
    INFO("shadow " << n.shadow_dark << "/" << n.shadow_n << " control " << n.control_same << "/" << n.control_n);
    REQUIRE(n.shadow_n >= 20);
    REQUIRE(n.control_n >= 20);
    CHECK(n.shadow_dark >= n.shadow_n * 95 / 100);
    CHECK(n.control_same >= n.control_n * 95 / 100);
}

TEST_CASE("scene renderer: the shadow stays attached as the forceps tip approaches the retina (no peter-panning)",
          "[render][scene]") {
    SceneRenderer* r = renderer();
    if (!r) return;
    // The depth cue: near contact the tip and its shadow meet. Lower the tip towards a retina point and check that
    // the shadow is still where the light predicts, and that the predicted tip-to-shadow distance in the image
    // shrinks (what the surgeon reads).
    const Vector3f on_retina = Vector3f(1.8f, -1.2f, -std::sqrt(144.0f - 1.8f * 1.8f - 1.2f * 1.2f));
    float last_gap_px = 1e9f;
    for (float height : {2.0f, 0.8f, 0.3f}) {
        Scene s;
        const Vector3f tip = on_retina - height * on_retina.normalized();
        s.forceps = Posed(col::make_forceps(), tip, tip - Vector3f(8.5f, 0.0f, 8.5f));
        const ShadowCounts n = forceps_shadow(*r, s, height < 0.5f ? "scene_shadow_near_contact" : nullptr);
        const auto shadow_tip = hit_wall(s.light.tip, tip - s.light.tip);
        REQUIRE(shadow_tip);
        const float gap_px = (project(r->config(), 0, *shadow_tip) - project(r->config(), 0, tip)).norm();
        INFO("height " << height << " mm: shadow " << n.shadow_dark << "/" << n.shadow_n << " control "
                       << n.control_same << "/" << n.control_n << ", tip-shadow gap " << gap_px << " px");
        REQUIRE(n.shadow_n >= 10);
        CHECK(n.shadow_dark >= n.shadow_n * 95 / 100);
        CHECK(n.control_same >= n.control_n * 95 / 100);
        CHECK(gap_px < last_gap_px);
        last_gap_px = gap_px;
    }
}

TEST_CASE("scene renderer: the forceps shadow the membrane itself", "[render][scene]") {
    SceneRenderer* r = renderer();
    if (!r) return;
    const RenderConfig& c = r->config();
    Scene s;
    const Vector3f tip(-1.5f, 0.5f, -9.6f);  // 1 mm above the membrane
    s.forceps = Posed(col::make_forceps(), tip, tip - Vector3f(8.5f, 0.0f, 8.5f));
    StereoImages with, without;
    r->render(s.frame(true, true, true), with);
    r->render(s.frame(true, false, true), without);
    CHECK(write_views("scene_shadow_on_membrane.png", with));
    int n = 0, dark = 0;
    for (int view = 0; view < 2; ++view) {
        const Vector3f cam = view_position(c, view);
        for (float back = 0.3f; back < 12.0f; back += 0.1f) {
            // Where the light's ray through the forceps axis meets the membrane plane, inside the patch.
            const Vector3f q = s.forceps.tip - back * s.forceps.forward;
            const Vector3f d = q - s.light.tip;
            const float t = (s.membrane_centre.z() - s.light.tip.z()) / d.z();
            const Vector3f m = s.light.tip + t * d;
            if (std::abs(m.x() - s.membrane_centre.x()) > 2.2f || std::abs(m.y() - s.membrane_centre.y()) > 2.2f) continue;
            if (segments_distance(cam, m, s.forceps.tip, s.forceps.back()) < 0.8f) continue;
            const Eigen::Vector2f px = project(c, view, m);
            const double la = luminance(view == 0 ? with.left_rgba : with.right_rgba, px);
            const double lb = luminance(view == 0 ? without.left_rgba : without.right_rgba, px);
            ++n;
            dark += la < 0.85 * lb;
            UNSCOPED_INFO("membrane shadow px " << px.transpose() << ": " << la << " vs " << lb);
        }
    }
    INFO("dark " << dark << "/" << n);
    REQUIRE(n >= 10);
    CHECK(dark >= n * 9 / 10);
}

TEST_CASE("scene renderer: the membrane casts a partial shadow on the retina", "[render][scene]") {
    SceneRenderer* r = renderer();
    if (!r) return;
    const RenderConfig& c = r->config();
    Scene s;
    s.aim_light(Vector3f(-6.5f, 1.5f, -6.5f), Vector3f(1.0f, 1.5f, -12.0f));  // oblique: the shadow falls aside
    StereoImages with, without;
    r->render(s.frame(true, false, true), with);
    r->render(s.frame(false, false, true), without);
    CHECK(write_views("scene_membrane_shadow.png", with));
    // Rays from the light through the membrane's interior to the retina, where the view does not see the membrane.
    int n = 0, partial = 0;
    for (float u = -2.2f; u <= 2.2f; u += 0.2f)
        for (float v = -2.2f; v <= 2.2f; v += 0.2f) {
            const Vector3f m = s.membrane_centre + Vector3f(u, v, 0);
            const auto wall = hit_wall(s.light.tip, m - s.light.tip);
            if (!wall || s.behind_membrane(c, 0, *wall, 0.2f)) continue;
            const Eigen::Vector2f px = project(c, 0, *wall);
            const double la = luminance(with.left_rgba, px), lb = luminance(without.left_rgba, px);
            ++n;
            // Linear light is cut to (1 - membrane_shadow) of the spot; ambient and coaxial light remain.
            partial += la < 0.92 * lb && la > 0.5 * lb;
        }
    INFO("partial shadow at " << partial << "/" << n);
    REQUIRE(n >= 10);
    CHECK(partial >= n * 9 / 10);
}

TEST_CASE("scene renderer: rendering is deterministic and frames do not leak into each other", "[render][scene]") {
    SceneRenderer* r = renderer();
    if (!r) return;
    Scene s;
    StereoImages a, b, other;
    r->render(s.frame(true, true, true), a);
    r->render(s.frame(false, false, true), other);
    r->render(s.frame(true, true, true), b);
    CHECK(a.left_rgba == b.left_rgba);
    CHECK(a.right_rgba == b.right_rgba);
    CHECK(a.left_rgba != other.left_rgba);
    CHECK(a.left_rgba != a.right_rgba);
}

TEST_CASE("scene renderer: a retina mesh is drawn as fundus and the scene without a light pipe is dim",
          "[render][scene]") {
    SceneRenderer* r = renderer();
    if (!r) return;
    Scene s;
    eyesim::sim::TriangleMesh retina = eyesim::sim::make_retina_hemisphere(kEyeR, 20, 64);
    // Lift a patch off the wall (as in retina relocation): it must appear in front of the eye sphere.
    for (Vector3f& v : retina.vertices_mm)
        if (v.head<2>().norm() < 3.0f) v *= 1.0f - 0.12f * (1.0f - v.head<2>().norm() / 3.0f);
    SceneFrame f = s.frame(false, true, true);
    f.tissue = MeshView{retina.vertices_mm, retina.triangles};
    f.tissue_is_retina = true;
    StereoImages lit, dark;
    r->render(f, lit);
    CHECK(write_views("scene_retina.png", lit));
    const Eigen::Vector2f centre(kW / 2.0f, kH / 2.0f);
    const uint8_t* p = &lit.left_rgba[(size_t(centre.y()) * kW + size_t(centre.x())) * 4];
    CHECK(p[0] > p[1]);
    f.instruments = {};
    r->render(f, dark);
    CHECK(luminance(dark.left_rgba, centre, 20) < 0.6 * luminance(lit.left_rgba, centre, 20));
    CHECK(luminance(dark.left_rgba, centre, 20) > 3.0);  // the microscope's own dim light still shows it
}

TEST_CASE("scene renderer: malformed meshes are skipped, never crash or smear the picture", "[render][scene]") {
    SceneRenderer* r = renderer();
    if (!r) return;
    Scene s;
    StereoImages clean, bad;
    r->render(s.frame(false, true, true), clean);
    // Append triangles with out-of-range indices and a vertex that is NaN to the tissue; add an empty instrument.
    std::vector<Vector3f> verts = {{0, 0, -10}, {1, 0, -10}, {0, 1, -10}, {NAN, 0.0f, -10.0f}};
    std::vector<std::array<uint32_t, 3>> tris = {{0, 1, 7}, {0, 1, 3}, {3, 2, 1}, {100, 200, 300}};
    SceneFrame f = s.frame(false, true, true);
    f.tissue = MeshView{verts, tris};
    std::vector<InstrumentView> instruments(f.instruments.begin(), f.instruments.end());
    instruments.push_back(InstrumentView{MeshView{}, Vector3f(NAN, 0, 0), Vector3f(0, 0, -1), false});
    f.instruments = instruments;
    r->render(f, bad);
    CHECK(bad.left_rgba == clean.left_rgba);
    CHECK(bad.right_rgba == clean.right_rgba);
    // A light pipe with a NaN axis does not light the scene (no spot), but the view still renders.
    Scene s2;
    s2.light.forward = Vector3f(NAN, 0, 0);
    StereoImages no_spot;
    r->render(s2.frame(false, true, true), no_spot);
    const Eigen::Vector2f centre(kW / 2.0f, kH / 2.0f);
    CHECK(luminance(no_spot.left_rgba, centre, 20) < 0.6 * luminance(clean.left_rgba, centre, 20));
}

TEST_CASE("scene instruments: a posed simulation instrument becomes an eye-frame view", "[render][scene]") {
    col::PosedInstrument forceps(col::make_forceps());
    Eigen::Isometry3f pose = Eigen::Isometry3f::Identity();
    pose.linear() = Eigen::AngleAxisf(0.7f, Vector3f(1, 2, 3).normalized()).toRotationMatrix();
    pose.translation() = Vector3f(1.0f, -2.0f, -8.0f);
    forceps.set_state(20.0f, pose);
    std::vector<Vector3f> eye;
    const InstrumentView v = eyesim::render::make_instrument_view(forceps, eye);
    REQUIRE(v.mesh.vertices_eye_mm.size() == forceps.vertices_local_mm().size());
    REQUIRE(v.mesh.triangles.size() == forceps.instrument().mesh.triangles.size());
    CHECK(v.mesh.vertices_eye_mm.data() == eye.data());
    float worst = 0;
    for (size_t i = 0; i < eye.size(); ++i) {
        // Independent: rotation then translation, written out.
        const Vector3f expect = pose.linear() * forceps.vertices_local_mm()[i] + pose.translation();
        worst = std::max(worst, (eye[i] - expect).norm());
    }
    CHECK(worst < 1e-5f);
    CHECK((v.tip_eye_mm - Vector3f(1.0f, -2.0f, -8.0f)).norm() < 1e-6f);
    CHECK((v.forward_eye - pose.linear().col(2)).norm() < 1e-6f);
    CHECK_FALSE(v.is_light_pipe);
    col::PosedInstrument pipe(col::make_light_pipe());
    pipe.set_state(0.0f, pose);
    CHECK(eyesim::render::make_instrument_view(pipe, eye).is_light_pipe);
}

TEST_CASE("scene renderer: invalid sizes are refused with a reason", "[render][scene]") {
    std::string error;
    CHECK(SceneRenderer::create(0, 480, error) == nullptr);
    CHECK(error.find("invalid view size") != std::string::npos);
}

TEST_CASE("png writer: images read back identically with OpenCV", "[render][png]") {
    // Smooth gradients, long constant runs (matches up to 258 bytes, distances up to the 32 KiB window) and
    // pseudo-random noise (literals) in one image.
    const int w = 301, h = 157;
    std::vector<uint8_t> rgba(size_t(w) * h * 4);
    uint32_t noise = 12345;
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
            uint8_t* q = &rgba[(size_t(y) * w + x) * 4];
            noise ^= noise << 13;
            noise ^= noise >> 17;
            noise ^= noise << 5;
            if (y < 50) {
                q[0] = uint8_t(x * 7 + y);
                q[1] = uint8_t(y * 13 ^ x);
                q[2] = uint8_t((x * y) >> 3);
                q[3] = uint8_t(255 - ((x + y) & 63));
            } else if (y < 100) {
                q[0] = q[1] = q[2] = x < 150 ? 0 : 200;
                q[3] = 255;
            } else {
                std::memcpy(q, &noise, 4);
            }
        }
    std::string error;
    const std::string path = out_path("png_roundtrip.png");
    REQUIRE(eyesim::render::write_png(path, w, h, rgba.data(), error));
    const cv::Mat m = cv::imread(path, cv::IMREAD_UNCHANGED);
    REQUIRE(m.type() == CV_8UC4);
    REQUIRE(m.cols == w);
    REQUIRE(m.rows == h);
    int mismatches = 0;
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
            const cv::Vec4b b = m.at<cv::Vec4b>(y, x);  // OpenCV orders BGRA
            const uint8_t* q = &rgba[(size_t(y) * w + x) * 4];
            mismatches += b[2] != q[0] || b[1] != q[1] || b[0] != q[2] || b[3] != q[3];
        }
    CHECK(mismatches == 0);
    // Compressed: well below the raw pixel bytes (the noise third cannot compress).
    std::FILE* f = std::fopen(path.c_str(), "rb");
    REQUIRE(f != nullptr);
    std::fseek(f, 0, SEEK_END);
    const long size = std::ftell(f);
    std::fclose(f);
    CHECK(size < long(rgba.size()) * 6 / 10);

    // Side by side: left view on the left.
    StereoImages s;
    s.width = w;
    s.height = h;
    s.left_rgba = rgba;
    s.right_rgba.assign(rgba.size(), 9);
    REQUIRE(eyesim::render::write_side_by_side_png(out_path("png_sbs.png"), s, error));
    const cv::Mat sbs = cv::imread(out_path("png_sbs.png"), cv::IMREAD_UNCHANGED);
    REQUIRE(sbs.cols == 2 * w);
    CHECK(sbs.at<cv::Vec4b>(10, 20)[2] == rgba[(10 * size_t(w) + 20) * 4]);
    CHECK(sbs.at<cv::Vec4b>(10, w + 20) == cv::Vec4b(9, 9, 9, 9));

    // Bad input: a clear error, no file.
    CHECK_FALSE(eyesim::render::write_png("/nonexistent-dir/x.png", w, h, rgba.data(), error));
    CHECK(error.find("/nonexistent-dir/x.png") != std::string::npos);
    s.right_rgba.resize(10);
    CHECK_FALSE(eyesim::render::write_side_by_side_png(out_path("bad.png"), s, error));
}
