#pragma once
/// \file
/// The naive OpenCV pipeline of the benchmarks, kept as a labelled row beside the fair peer (opencv_peer.hpp):
/// UYVY → BGR → HSV over the whole field, inRange per class, 8-connected connectedComponentsWithStats with 32-bit
/// labels, then a binary centroid or saturation-weighted moments (no background subtracted) per component.

#include "detection.hpp"

#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include <cstdint>
#include <vector>

namespace eyesim::fpga::bench {

/// The naive pipeline with its reusable images.
struct OpenCvPipeline {
    cv::Mat bgr, hsv, mask, mask2, labels, stats, centroids;
    bool weighted = true;
    std::vector<Detection> run(const uint8_t* uyvy, int height) {
        std::vector<Detection> out;
        const cv::Mat src(height, 720, CV_8UC2, const_cast<uint8_t*>(uyvy));
        cv::cvtColor(src, bgr, cv::COLOR_YUV2BGR_UYVY);
        cv::cvtColor(bgr, hsv, cv::COLOR_BGR2HSV);
        // Hue (OpenCV 0..180): red 0, yellow 27, green 64, blue 113; saturation ≥ 40 (edges included), V ≥ 30.
        static const int lo[5] = {0, 172, 52, 100, 18}, hi[5] = {0, 8, 76, 126, 36};
        for (int c = 1; c <= 4; ++c) {
            if (c == 1) {
                cv::inRange(hsv, cv::Scalar(0, 40, 30), cv::Scalar(hi[1], 255, 255), mask);
                cv::inRange(hsv, cv::Scalar(lo[1], 40, 30), cv::Scalar(180, 255, 255), mask2);
                mask |= mask2;
            } else {
                cv::inRange(hsv, cv::Scalar(lo[c], 40, 30), cv::Scalar(hi[c], 255, 255), mask);
            }
            const int n = cv::connectedComponentsWithStats(mask, labels, stats, centroids, 8, CV_32S);
            for (int i = 1; i < n; ++i) {
                if (stats.at<int>(i, cv::CC_STAT_AREA) < 2) continue;
                if (!weighted) {
                    out.push_back({c, centroids.at<double>(i, 0), centroids.at<double>(i, 1)});
                    continue;
                }
                // Saturation-weighted moments over the component's box (threshold + moments).
                const cv::Rect r(stats.at<int>(i, cv::CC_STAT_LEFT), stats.at<int>(i, cv::CC_STAT_TOP),
                                 stats.at<int>(i, cv::CC_STAT_WIDTH), stats.at<int>(i, cv::CC_STAT_HEIGHT));
                cv::Mat1b sat(r.height, r.width);
                for (int y = 0; y < r.height; ++y)
                    for (int x = 0; x < r.width; ++x)
                        sat(y, x) = labels.at<int>(r.y + y, r.x + x) == i ? hsv.at<cv::Vec3b>(r.y + y, r.x + x)[1] : 0;
                const cv::Moments m = cv::moments(sat, false);
                if (m.m00 > 0) out.push_back({c, r.x + m.m10 / m.m00, r.y + m.m01 / m.m00});
            }
        }
        return out;
    }
};

}  // namespace eyesim::fpga::bench
