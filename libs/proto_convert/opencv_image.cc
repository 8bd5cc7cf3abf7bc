#include "libs/proto_convert/opencv_image.h"

#include <opencv2/core.hpp>

#include <cstring>
#include <stdexcept>

namespace picking::proto_convert {
namespace {

int CvType(pb::PixelFormat format) {
  switch (format) {
    case pb::PIXEL_FORMAT_MONO8:
      return CV_8UC1;
    case pb::PIXEL_FORMAT_MONO16:
      return CV_16UC1;
    case pb::PIXEL_FORMAT_RGB8:
      return CV_8UC3;
    case pb::PIXEL_FORMAT_FLOAT32:
      return CV_32FC1;
    default:
      throw std::invalid_argument("image pixel format is unspecified or unknown");
  }
}

}  // namespace

void ToCvMat(const Image& image, cv::Mat* out) {
  const int type = CvType(image.format);
  const std::size_t row_bytes = image.width * BytesPerPixel(image.format);
  if (image.width == 0 || image.height == 0 || image.data.size() != row_bytes * image.height) {
    throw std::invalid_argument("image '" + image.name + "': " + std::to_string(image.width) + "x" +
                                std::to_string(image.height) + " does not match " +
                                std::to_string(image.data.size()) + " bytes");
  }
  out->create(static_cast<int>(image.height), static_cast<int>(image.width), type);
  for (std::uint32_t r = 0; r < image.height; ++r) {
    std::memcpy(out->ptr(static_cast<int>(r)), image.data.data() + r * row_bytes, row_bytes);
  }
}

Image FromCvMat(const cv::Mat& mat, const std::string& name, std::uint32_t index) {
  Image image;
  switch (mat.type()) {
    case CV_8UC1:
      image.format = pb::PIXEL_FORMAT_MONO8;
      break;
    case CV_16UC1:
      image.format = pb::PIXEL_FORMAT_MONO16;
      break;
    case CV_8UC3:
      image.format = pb::PIXEL_FORMAT_RGB8;
      break;
    case CV_32FC1:
      image.format = pb::PIXEL_FORMAT_FLOAT32;
      break;
    default:
      throw std::invalid_argument("image '" + name + "': OpenCV type " +
                                  std::to_string(mat.type()) +
                                  " has no wire format (use 8UC1, 16UC1, 8UC3 or 32FC1)");
  }
  if (mat.empty()) throw std::invalid_argument("image '" + name + "' is empty");
  image.width = static_cast<std::uint32_t>(mat.cols);
  image.height = static_cast<std::uint32_t>(mat.rows);
  image.name = name;
  image.index = index;
  const std::size_t row_bytes = image.width * BytesPerPixel(image.format);
  image.data.resize(row_bytes * image.height);
  for (int r = 0; r < mat.rows; ++r) {
    std::memcpy(image.data.data() + r * row_bytes, mat.ptr(r), row_bytes);
  }
  return image;
}

}  // namespace picking::proto_convert
