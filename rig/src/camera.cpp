#include "eyesim/rig/camera.hpp"

#include "eyesim/rig/error.hpp"

#include <Eigen/Geometry>
#include <opencv2/calib3d.hpp>
#include <opencv2/core/persistence.hpp>

#include <cmath>
#include <filesystem>
#include <fmt/format.h>

namespace eyesim::rig {

Eigen::Vector2d CameraModel::distort_normalized(const Eigen::Vector2d& xy) const {
    // OpenCV's 5-coefficient model (cv::projectPoints), written in the same order of operations.
    const double x = xy.x(), y = xy.y();
    const double r2 = x * x + y * y;
    const double r4 = r2 * r2, r6 = r4 * r2;
    const double radial = 1 + dist[0] * r2 + dist[1] * r4 + dist[4] * r6;
    const double a1 = 2 * x * y, a2 = r2 + 2 * x * x, a3 = r2 + 2 * y * y;
    const double xd = x * radial + dist[2] * a1 + dist[3] * a2;
    const double yd = y * radial + dist[2] * a3 + dist[3] * a1;
    return {xd * fx + cx, yd * fy + cy};
}

Eigen::Matrix2d CameraModel::distort_jacobian(const Eigen::Vector2d& xy) const {
    const double x = xy.x(), y = xy.y();
    const double r2 = x * x + y * y;
    const double radial = 1 + dist[0] * r2 + dist[1] * r2 * r2 + dist[4] * r2 * r2 * r2;
    const double drad_dr2 = dist[0] + 2 * dist[1] * r2 + 3 * dist[4] * r2 * r2;
    const double dr_dx = 2 * x * drad_dr2, dr_dy = 2 * y * drad_dr2;
    const double p1 = dist[2], p2 = dist[3];
    Eigen::Matrix2d J;
    J(0, 0) = fx * (radial + x * dr_dx + 2 * p1 * y + 6 * p2 * x);
    J(0, 1) = fx * (x * dr_dy + 2 * p1 * x + 2 * p2 * y);
    J(1, 0) = fy * (y * dr_dx + 2 * p1 * x + 2 * p2 * y);
    J(1, 1) = fy * (radial + y * dr_dy + 6 * p1 * y + 2 * p2 * x);
    return J;
}

std::optional<Eigen::Vector2d> CameraModel::undistort_to_normalized(const Eigen::Vector2d& frame_px) const {
    Eigen::Vector2d q((frame_px.x() - cx) / fx, (frame_px.y() - cy) / fy);
    for (int it = 0; it < 60; ++it) {
        const Eigen::Vector2d r = distort_normalized(q) - frame_px;
        const Eigen::Matrix2d J = distort_jacobian(q);
        const double det = J.determinant();
        if (!(std::abs(det) > 1e-12)) return std::nullopt;
        const Eigen::Vector2d step = J.inverse() * r;
        q -= step;
        if (!q.allFinite() || q.squaredNorm() > 1e6) return std::nullopt;
        if (step.norm() < 1e-13) return q;
    }
    const Eigen::Vector2d r = distort_normalized(q) - frame_px;
    if (r.norm() < 1e-9) return q;
    return std::nullopt;
}

std::optional<Eigen::Vector2d> CameraModel::project_frame(const Eigen::Vector3d& x_rig_mm) const {
    const Eigen::Vector3d p = to_camera(x_rig_mm);
    if (!(p.z() > 1e-6)) return std::nullopt;
    const double iz = 1.0 / p.z();
    const Eigen::Vector2d q(p.x() * iz, p.y() * iz);
    if (q.squaredNorm() > max_r2) return std::nullopt;
    return distort_normalized(q);
}

std::optional<Eigen::Vector2d> CameraModel::project_field(const Eigen::Vector3d& x_rig_mm, int parity) const {
    auto f = project_frame(x_rig_mm);
    if (!f) return std::nullopt;
    return frame_to_field_px(*f, parity);
}

FieldTiming CameraModel::field_timing(int64_t index) const {
    return eyesim::rig::field_timing(index, field_time_offset_us, exposure_us, first_field_parity);
}

cv::Vec3d CameraModel::rvec() const {
    cv::Matx33d R;
    for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c) R(r, c) = R_cam_rig(r, c);
    cv::Vec3d rv;
    cv::Rodrigues(R, rv);
    return rv;
}

namespace {

/// Camera at `center` looking at `target`, image "up" towards +z of the rig.
CameraModel look_at(const std::string& name, const Eigen::Vector3d& center, const Eigen::Vector3d& target,
                    double roll_rad) {
    CameraModel c;
    c.name = name;
    const Eigen::Vector3d z = (target - center).normalized();
    const Eigen::Vector3d up(0, 0, 1);
    Eigen::Vector3d y = -(up - up.dot(z) * z).normalized();  // image y points down = away from rig +z
    Eigen::Vector3d x = y.cross(z);
    Eigen::Matrix3d R;
    R.row(0) = x.transpose();
    R.row(1) = y.transpose();
    R.row(2) = z.transpose();
    // Small mounting roll about the optical axis.
    R = Eigen::AngleAxisd(roll_rad, Eigen::Vector3d::UnitZ()).toRotationMatrix() * R;
    c.R_cam_rig = R;
    c.t_cam_rig_mm = -R * center;
    return c;
}

}  // namespace

std::vector<CameraModel> default_rig() {
    std::vector<CameraModel> cams;
    const double az_deg[3] = {90.0, 210.0, 330.0};
    const double offsets_us[3] = {0.0, 6700.0, 13300.0};
    // Slightly different lenses and mounting per camera, as on a real rig.
    const double fx[3] = {615.0, 612.4, 617.9}, fy[3] = {640.2, 637.5, 643.1};
    const double ccx[3] = {362.3, 356.8, 360.9}, ccy[3] = {284.6, 290.2, 288.7};
    const double roll[3] = {0.012, -0.008, 0.02};
    const double dist[3][5] = {{-0.281, 0.092, 0.0008, -0.0005, -0.012},
                               {-0.274, 0.085, -0.0006, 0.0004, -0.009},
                               {-0.288, 0.098, 0.0003, 0.0007, -0.015}};
    const double pi = 3.14159265358979323846;
    for (int i = 0; i < 3; ++i) {
        const double a = az_deg[i] * pi / 180.0;
        const double horiz = 68.0, z = -52.0;
        const Eigen::Vector3d center(horiz * std::cos(a), horiz * std::sin(a), z);
        CameraModel c = look_at(fmt::format("cam{}", i), center, Eigen::Vector3d(0, 0, 14.0), roll[i]);
        c.fx = fx[i];
        c.fy = fy[i];
        c.cx = ccx[i];
        c.cy = ccy[i];
        for (int k = 0; k < 5; ++k) c.dist[k] = dist[i][k];
        c.field_time_offset_us = offsets_us[i];
        cams.push_back(c);
    }
    return cams;
}

// ---- rig.yaml ----

namespace {

[[noreturn]] void fail(const std::string& path, const std::string& key, const std::string& why) {
    throw RigError(fmt::format("{}: {}: {}", path, key, why));
}

cv::Mat read_matrix(const cv::FileNode& cam, const std::string& path, const std::string& cam_key, const char* key,
                    int rows, int cols) {
    const std::string full = cam_key + "." + key;
    const cv::FileNode n = cam[key];
    if (n.empty() || n.isNone()) fail(path, full, "missing");
    cv::Mat m;
    try {
        n >> m;
    } catch (const cv::Exception&) {
        fail(path, full, "not an OpenCV matrix");
    }
    if (m.empty()) fail(path, full, "not an OpenCV matrix");
    if (m.channels() != 1) fail(path, full, "must have one channel");
    // Accept row or column vectors of the right length for vectors.
    const bool vec_ok = (rows == 1 || cols == 1) && static_cast<int>(m.total()) == rows * cols &&
                        (m.rows == 1 || m.cols == 1);
    if (!(m.rows == rows && m.cols == cols) && !vec_ok)
        fail(path, full, fmt::format("expected {}x{}, got {}x{}", rows, cols, m.rows, m.cols));
    cv::Mat d;
    m.convertTo(d, CV_64F);
    d = d.reshape(1, rows);
    for (int r = 0; r < d.rows; ++r)
        for (int c = 0; c < d.cols; ++c)
            if (!std::isfinite(d.at<double>(r, c)))
                fail(path, fmt::format("{}[{},{}]", full, r, c), fmt::format("not finite ({})", d.at<double>(r, c)));
    return d;
}

double read_real(const cv::FileNode& cam, const std::string& path, const std::string& cam_key, const char* key,
                 bool required, double fallback) {
    const cv::FileNode n = cam[key];
    const std::string full = cam_key + "." + key;
    if (n.empty() || n.isNone()) {
        if (required) fail(path, full, "missing");
        return fallback;
    }
    if (!n.isReal() && !n.isInt()) fail(path, full, "not a number");
    const double v = n.real();
    if (!std::isfinite(v)) fail(path, full, fmt::format("not finite ({})", v));
    return v;
}

}  // namespace

std::vector<CameraModel> load_rig_yaml(const std::string& path) {
    if (!std::filesystem::exists(path)) fail(path, "file", "missing");
    cv::FileStorage fs;
    try {
        if (!fs.open(path, cv::FileStorage::READ)) fail(path, "file", "cannot be opened as OpenCV FileStorage YAML");
    } catch (const cv::Exception&) {
        fail(path, "file", "not valid OpenCV FileStorage YAML");
    }
    const cv::FileNode root = fs.root();
    const double count_d = read_real(root, path, "", "camera_count", true, 0);
    const std::string count_key = "camera_count";
    if (count_d != std::floor(count_d) || count_d < 1 || count_d > 16)
        fail(path, count_key, fmt::format("must be an integer in 1..16, got {}", count_d));
    const int count = static_cast<int>(count_d);
    std::vector<CameraModel> cams;
    for (int i = 0; i < count; ++i) {
        const std::string key = fmt::format("cam{}", i);
        const cv::FileNode cn = fs[key];
        if (cn.empty() || !cn.isMap()) fail(path, key, "missing camera entry");
        CameraModel c;
        c.name = key;
        const double w = read_real(cn, path, key, "image_width", true, 0);
        const double h = read_real(cn, path, key, "image_height", true, 0);
        if (w != kFrameWidth || h != kFrameHeight)
            fail(path, key + ".image_width/image_height", fmt::format("must be 720x576 (PAL), got {}x{}", w, h));
        c.image_width = kFrameWidth;
        c.image_height = kFrameHeight;
        const cv::Mat K = read_matrix(cn, path, key, "K", 3, 3);
        if (K.at<double>(0, 1) != 0 || K.at<double>(1, 0) != 0 || K.at<double>(2, 0) != 0 ||
            K.at<double>(2, 1) != 0 || K.at<double>(2, 2) != 1)
            fail(path, key + ".K", "must be [fx 0 cx; 0 fy cy; 0 0 1]");
        c.fx = K.at<double>(0, 0);
        c.fy = K.at<double>(1, 1);
        c.cx = K.at<double>(0, 2);
        c.cy = K.at<double>(1, 2);
        if (!(c.fx > 0) || !(c.fy > 0)) fail(path, key + ".K", "focal lengths must be positive");
        const cv::Mat D = read_matrix(cn, path, key, "dist", 1, 5);
        for (int k = 0; k < 5; ++k) c.dist[k] = D.at<double>(0, k);
        const cv::Mat R = read_matrix(cn, path, key, "R", 3, 3);
        for (int r = 0; r < 3; ++r)
            for (int cc = 0; cc < 3; ++cc) c.R_cam_rig(r, cc) = R.at<double>(r, cc);
        const double ortho = (c.R_cam_rig.transpose() * c.R_cam_rig - Eigen::Matrix3d::Identity()).norm();
        if (ortho > 1e-6 || c.R_cam_rig.determinant() < 0)
            fail(path, key + ".R", fmt::format("not a rotation (|R'R-I| = {:.3g}, det = {:.6f})", ortho,
                                               c.R_cam_rig.determinant()));
        const cv::Mat t = read_matrix(cn, path, key, "t", 3, 1);
        for (int r = 0; r < 3; ++r) c.t_cam_rig_mm(r) = t.at<double>(r, 0);
        const double par = read_real(cn, path, key, "first_field_parity", false, 0);
        if (par != 0 && par != 1) fail(path, key + ".first_field_parity", fmt::format("must be 0 or 1, got {}", par));
        c.first_field_parity = static_cast<int>(par);
        c.field_time_offset_us = read_real(cn, path, key, "field_time_offset_us", false, 0.0);
        c.exposure_us = read_real(cn, path, key, "exposure_us", false, 4000.0);
        if (!(c.exposure_us > 0) || c.exposure_us > kFieldPeriodUs)
            fail(path, key + ".exposure_us", fmt::format("must be in (0, 20000], got {}", c.exposure_us));
        c.max_r2 = read_real(cn, path, key, "max_r2", false, 1.0);
        if (!(c.max_r2 > 0)) fail(path, key + ".max_r2", fmt::format("must be positive, got {}", c.max_r2));
        cams.push_back(c);
    }
    return cams;
}

void save_rig_yaml(const std::string& path, const std::vector<CameraModel>& cams) {
    cv::FileStorage fs;
    try {
        if (!fs.open(path, cv::FileStorage::WRITE | cv::FileStorage::FORMAT_YAML))
            fail(path, "file", "cannot be written");
        fs << "camera_count" << static_cast<int>(cams.size());
        for (size_t i = 0; i < cams.size(); ++i) {
            const CameraModel& c = cams[i];
            cv::Mat K = (cv::Mat_<double>(3, 3) << c.fx, 0, c.cx, 0, c.fy, c.cy, 0, 0, 1);
            cv::Mat D = (cv::Mat_<double>(1, 5) << c.dist[0], c.dist[1], c.dist[2], c.dist[3], c.dist[4]);
            cv::Mat R(3, 3, CV_64F), t(3, 1, CV_64F);
            for (int r = 0; r < 3; ++r) {
                for (int cc = 0; cc < 3; ++cc) R.at<double>(r, cc) = c.R_cam_rig(r, cc);
                t.at<double>(r, 0) = c.t_cam_rig_mm(r);
            }
            fs << fmt::format("cam{}", i) << "{";
            fs << "image_width" << c.image_width << "image_height" << c.image_height;
            fs << "K" << K << "dist" << D << "R" << R << "t" << t;
            fs << "first_field_parity" << c.first_field_parity;
            fs << "field_time_offset_us" << c.field_time_offset_us;
            fs << "exposure_us" << c.exposure_us;
            fs << "max_r2" << c.max_r2;
            fs << "}";
        }
        fs.release();
    } catch (const cv::Exception&) {
        fail(path, "file", "cannot be written");
    }
}

}  // namespace eyesim::rig
