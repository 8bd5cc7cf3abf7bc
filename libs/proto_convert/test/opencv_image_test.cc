#include "libs/proto_convert/opencv_image.h"

#include <gtest/gtest.h>

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>

namespace picking::proto_convert {
namespace {

TEST(OpenCvImageTest, RealImageRoundTripsThroughChunks) {
  const cv::Mat gray = cv::imread(std::string(PICKING_TEST_DATA_DIR) + "/calibration/left01.jpg",
                                  cv::IMREAD_GRAYSCALE);
  ASSERT_FALSE(gray.empty());
  const Image image = FromCvMat(gray, "left01", 1);
  EXPECT_EQ(image.width, 640u);
  EXPECT_EQ(image.height, 480u);
  ImageAssembler assembler;
  bool done = false;
  for (const auto& chunk : ImageToChunks(image, 64 * 1024)) done = assembler.Add(chunk);
  ASSERT_TRUE(done);
  cv::Mat back;
  ToCvMat(assembler.completed(), &back);
  EXPECT_EQ(cv::norm(gray, back, cv::NORM_INF), 0.0);
}

TEST(OpenCvImageTest, EveryWireFormatRoundTrips) {
  for (int type : {CV_8UC1, CV_16UC1, CV_8UC3, CV_32FC1}) {
    cv::Mat m(7, 5, type);
    cv::randu(m, 0, 200);
    cv::Mat back;
    ToCvMat(FromCvMat(m, "m"), &back);
    EXPECT_EQ(back.type(), type);
    EXPECT_EQ(cv::norm(m, back, cv::NORM_INF), 0.0);
  }
}

TEST(OpenCvImageTest, RejectsTypesWithoutWireFormat) {
  EXPECT_THROW(FromCvMat(cv::Mat(3, 3, CV_64FC1), "d"), std::invalid_argument);
  EXPECT_THROW(FromCvMat(cv::Mat(), "empty"), std::invalid_argument);
  Image bad;
  bad.width = 4;
  bad.height = 4;
  bad.data.resize(3);
  cv::Mat out;
  EXPECT_THROW(ToCvMat(bad, &out), std::invalid_argument);
}

}  // namespace
}  // namespace picking::proto_convert
