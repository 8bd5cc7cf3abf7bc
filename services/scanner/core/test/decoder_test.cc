#include "services/scanner/core/decoder.h"

#include "services/scanner/core/synthetic_capture.h"

#include <gtest/gtest.h>

#include <stdexcept>
#include <string>

namespace picking::scanner {
namespace {

SyntheticScene TiltedPlane() {
  SyntheticScene scene;
  SyntheticPlane plane;
  plane.normal = Eigen::Vector3d(0.25, -0.1, -1.0).normalized();
  plane.offset_m = plane.normal.dot(Eigen::Vector3d(0, 0, 1.0));
  scene.planes.push_back(plane);
  return scene;
}

SyntheticScene SphereInFrontOfPlane() {
  SyntheticScene scene = TiltedPlane();
  SyntheticSphere sphere;
  sphere.center_m = Eigen::Vector3d(-0.02, 0.03, 0.8);
  sphere.radius_m = 0.08;
  scene.spheres.push_back(sphere);
  return scene;
}

struct Score {
  double decoded_fraction = 0;
  double precision = 0;  // Decoded pixels with exactly the true column and row.
  std::size_t decoded = 0;
};

Score Evaluate(const SyntheticCapture& capture, const CorrespondenceMap& map) {
  Score score;
  std::size_t correct = 0;
  for (std::size_t i = 0; i < map.valid.size(); ++i) {
    if (!map.valid[i]) continue;
    ++score.decoded;
    correct += map.column[i] == capture.column[i] && map.row[i] == capture.row[i];
  }
  score.decoded_fraction = map.decoded_fraction();
  score.precision = score.decoded == 0 ? 0.0 : static_cast<double>(correct) / score.decoded;
  return score;
}

// The decoder's contract written as plainly as possible, pixel by pixel.
CorrespondenceMap ReferenceDecode(const PatternSequence& patterns,
                                  const std::vector<ImageView>& images,
                                  const DecoderOptions& options) {
  CorrespondenceMap map;
  map.width = images[0].width;
  map.height = images[0].height;
  const std::size_t n = static_cast<std::size_t>(map.width) * map.height;
  map.column.assign(n, 0);
  map.row.assign(n, 0);
  map.valid.assign(n, 0);
  for (int y = 0; y < map.height; ++y) {
    for (int x = 0; x < map.width; ++x) {
      const auto at = [&](int k) { return static_cast<int>(images[k].row(y)[x]); };
      bool ok = at(0) - at(1) >= options.min_contrast;
      std::uint32_t column_gray = 0;
      for (int b = 0; b < patterns.column_bits(); ++b) {
        const int p = at(patterns.ColumnImageIndex(b, false));
        const int q = at(patterns.ColumnImageIndex(b, true));
        ok = ok && std::abs(p - q) >= options.min_bit_contrast;
        column_gray = column_gray * 2 + (p > q);
      }
      std::uint32_t row_gray = 0;
      for (int b = 0; b < patterns.row_bits(); ++b) {
        const int p = at(patterns.RowImageIndex(b, false));
        const int q = at(patterns.RowImageIndex(b, true));
        ok = ok && std::abs(p - q) >= options.min_bit_contrast;
        row_gray = row_gray * 2 + (p > q);
      }
      const std::uint32_t column = GrayDecode(column_gray);
      const std::uint32_t row = GrayDecode(row_gray);
      ok = ok && column < static_cast<std::uint32_t>(patterns.projector_width()) &&
           row < static_cast<std::uint32_t>(patterns.projector_height());
      const std::size_t i = static_cast<std::size_t>(y) * map.width + x;
      if (ok) {
        map.valid[i] = 1;
        map.column[i] = static_cast<std::uint16_t>(column);
        map.row[i] = static_cast<std::uint16_t>(row);
        ++map.num_valid;
      }
    }
  }
  return map;
}

TEST(DecoderTest, NoiseFreePlaneDecodesExactly) {
  const ScannerRig rig = MakeExampleRig(640, 512);
  const PatternSequence patterns;
  const SyntheticCapture capture =
      RenderSyntheticCapture(rig, patterns, TiltedPlane(), SyntheticCaptureOptions{});
  const GrayCodeDecoder decoder(patterns);
  const CorrespondenceMap map = decoder.Decode(capture.views());
  const Score score = Evaluate(capture, map);
  std::size_t lit = 0;
  for (int c : capture.column) lit += c >= 0;
  RecordProperty("decoded_fraction", std::to_string(score.decoded_fraction));
  RecordProperty("precision", std::to_string(score.precision));
  EXPECT_GT(score.precision, 0.995);
  // Every lit pixel is decoded.
  EXPECT_EQ(map.num_valid, lit);
  EXPECT_GT(score.decoded_fraction, 0.9);
}

TEST(DecoderTest, NoisyCaptureMatchesTheReferenceDecoder) {
  const ScannerRig rig = MakeExampleRig(1280, 1024);
  const PatternSequence patterns;
  SyntheticCaptureOptions options;
  options.blur_sigma_px = 0.6;
  options.noise_sigma = 2.0;
  options.gamma = 1.3;
  options.ambient_level = 25.0;
  options.seed = 11;
  const SyntheticCapture capture =
      RenderSyntheticCapture(rig, patterns, SphereInFrontOfPlane(), options);
  DecoderOptions decoder_options;
  decoder_options.num_threads = 2;
  const GrayCodeDecoder decoder(patterns, decoder_options);
  const CorrespondenceMap map = decoder.Decode(capture.views());
  const CorrespondenceMap reference = ReferenceDecode(patterns, capture.views(), decoder_options);
  EXPECT_EQ(map.num_valid, reference.num_valid);
  EXPECT_TRUE(map.valid == reference.valid);
  EXPECT_TRUE(map.column == reference.column);
  EXPECT_TRUE(map.row == reference.row);
  const Score score = Evaluate(capture, map);
  std::cout << "noisy sphere + plane: decoded fraction " << score.decoded_fraction << ", precision "
            << score.precision << "\n";
  EXPECT_GT(score.decoded_fraction, 0.5);
  EXPECT_GT(score.precision, 0.8);
}

TEST(DecoderTest, ShadowsAreInvalid) {
  const ScannerRig rig = MakeExampleRig(640, 512);
  const PatternSequence patterns;
  SyntheticCaptureOptions options;
  options.noise_sigma = 1.5;
  options.ambient_level = 30.0;
  options.seed = 5;
  const SyntheticCapture capture =
      RenderSyntheticCapture(rig, patterns, SphereInFrontOfPlane(), options);
  const CorrespondenceMap map = GrayCodeDecoder(patterns).Decode(capture.views());
  std::size_t shadow = 0;
  std::size_t shadow_decoded = 0;
  for (std::size_t i = 0; i < map.valid.size(); ++i) {
    // A surface is seen but no projector light reaches it.
    if (!std::isnan(capture.depth_m[i]) && capture.column[i] < 0) {
      ++shadow;
      shadow_decoded += map.valid[i];
    }
  }
  ASSERT_GT(shadow, 1000u) << "the scene should cast a visible shadow";
  EXPECT_EQ(shadow_decoded, 0u);
}

TEST(DecoderTest, StridedViewsGiveTheSameResult) {
  const ScannerRig rig = MakeExampleRig(320, 256);
  const PatternSequence patterns;
  SyntheticCaptureOptions options;
  options.noise_sigma = 3.0;
  const SyntheticCapture capture =
      RenderSyntheticCapture(rig, patterns, SphereInFrontOfPlane(), options);
  // Copy each image into a buffer with 13 bytes of padding per row.
  const int stride = capture.width + 13;
  std::vector<std::vector<std::uint8_t>> padded;
  std::vector<ImageView> views;
  for (const auto& image : capture.images) {
    padded.emplace_back(static_cast<std::size_t>(stride) * capture.height, 0);
    for (int y = 0; y < capture.height; ++y) {
      std::copy_n(image.data() + y * capture.width, capture.width,
                  padded.back().data() + y * stride);
    }
  }
  for (const auto& buffer : padded) {
    views.push_back(ImageView{buffer.data(), capture.width, capture.height, stride});
  }
  const GrayCodeDecoder decoder(patterns);
  const CorrespondenceMap contiguous = decoder.Decode(capture.views());
  const CorrespondenceMap strided = decoder.Decode(views);
  EXPECT_GT(contiguous.num_valid, 0u);
  EXPECT_EQ(contiguous.num_valid, strided.num_valid);
  EXPECT_TRUE(contiguous.column == strided.column);
  EXPECT_TRUE(contiguous.row == strided.row);
  EXPECT_TRUE(contiguous.valid == strided.valid);
}

TEST(DecoderTest, RejectsBadInputWithoutTouchingTheOutput) {
  const PatternSequence patterns;
  const GrayCodeDecoder decoder(patterns);
  std::vector<std::uint8_t> pixels(64 * 48, 100);
  std::vector<std::uint8_t> other(60 * 48, 100);
  std::vector<ImageView> views(44, MakeImageView(pixels.data(), 64, 48));
  CorrespondenceMap map;
  map.width = 7;
  map.num_valid = 3;

  const auto expect_error = [&](const std::vector<ImageView>& images, const std::string& text) {
    try {
      decoder.Decode(images, &map);
      ADD_FAILURE() << "expected std::invalid_argument containing '" << text << "'";
    } catch (const std::invalid_argument& e) {
      EXPECT_NE(std::string(e.what()).find(text), std::string::npos) << e.what();
    }
    EXPECT_EQ(map.width, 7);
    EXPECT_EQ(map.num_valid, 3u);
    EXPECT_TRUE(map.column.empty());
  };

  expect_error(std::vector<ImageView>(42, MakeImageView(pixels.data(), 64, 48)),
               "expected 44 images");
  expect_error({}, "got 0");
  auto mismatched = views;
  mismatched[17] = MakeImageView(other.data(), 60, 48);
  expect_error(mismatched, "image 17 is 60 x 48 but image 0 is 64 x 48");
  auto missing = views;
  missing[3].data = nullptr;
  expect_error(missing, "image 3 has no data");
  auto bad_stride = views;
  bad_stride[5].stride_bytes = 10;
  expect_error(bad_stride, "image 5 has stride 10");
  auto empty = views;
  for (auto& v : empty) v.width = 0;
  expect_error(empty, "image 0 has size 0 x 48");

  EXPECT_THROW(GrayCodeDecoder(patterns, DecoderOptions{256, 5, 0}), std::invalid_argument);
  EXPECT_THROW(GrayCodeDecoder(patterns, DecoderOptions{10, -1, 0}), std::invalid_argument);
  EXPECT_THROW(GrayCodeDecoder(patterns, DecoderOptions{10, 5, -2}), std::invalid_argument);
}

TEST(DecoderTest, UniformImagesDecodeNothing) {
  const PatternSequence patterns;
  const GrayCodeDecoder decoder(patterns);
  std::vector<std::uint8_t> pixels(64 * 48, 200);
  const CorrespondenceMap map =
      decoder.Decode(std::vector<ImageView>(44, MakeImageView(pixels.data(), 64, 48)));
  EXPECT_EQ(map.num_valid, 0u);
  EXPECT_EQ(map.decoded_fraction(), 0.0);
}

}  // namespace
}  // namespace picking::scanner
