#pragma once

#include "libs/proto_convert/proto_convert.h"

namespace cv {
class Mat;
}

/// Conversions between streamed images (proto_convert::Image) and OpenCV matrices. OpenCV's
/// headers stay in the .cc: callers that use cv::Mat include OpenCV themselves.
namespace picking::proto_convert {

/// Copies an image into a cv::Mat: MONO8 -> CV_8UC1, MONO16 -> CV_16UC1, RGB8 -> CV_8UC3
/// (channel order r, g, b as sent; convert with cv::cvtColor for BGR functions),
/// FLOAT32 -> CV_32FC1. Throws std::invalid_argument for an unspecified format or a size
/// that does not match the data.
void ToCvMat(const Image& image, cv::Mat* out);

/// Copies a cv::Mat of one of the types above into an image with the given name and index.
/// Throws std::invalid_argument for other types or an empty matrix.
Image FromCvMat(const cv::Mat& mat, const std::string& name, std::uint32_t index = 0);

}  // namespace picking::proto_convert
