// `sope import` layouts against the other tools' own conventions: OpenCV's patterns come
// from cv::structured_light::GrayCodePattern::generate itself; SLStudio's are drawn with the
// formulas of its encoders (src/codec/CodecGrayCode.cpp, CodecPhaseShift2x3.cpp,
// CodecPhaseShift3.cpp, pstools::computePhaseVector), since SLStudio is not a library we can
// link. The images serve directly as camera images (camera size = projector size, camera
// pixel (x, y) sees projector pixel (x, y)), so the ground truth of every pixel is its own
// column and row. Gray layouts are decoded by sope::Decode and compared with our own
// patterns' decode; phase layouts (the phase decoder is being built separately) are checked
// image for image against DESIGN.md's phase formula and decoded with the reference N-step
// formula of the contract.
#include "capture/import_layouts.h"

#include <cmath>
#include <filesystem>
#include <functional>
#include <map>

#include <fmt/format.h>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <opencv2/core/eigen.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/structured_light.hpp>

#include "capture/foreign_calibration.h"
#include "core/error.h"
#include "core/file_util.h"
#include "core/units.h"
#include "decoder/decoder.h"
#include "projector/patterns.h"
#include "tests/opencv_graycode.h"
#include "tests/test_support.h"

namespace sope {
namespace {


void WriteImages(const std::string& directory, const std::vector<cv::Mat>& images,
                 const std::function<std::string(size_t)>& name) {
  std::filesystem::create_directories(directory);
  for (size_t i = 0; i < images.size(); ++i) {
    WriteImageAtomic(JoinPath(directory, name(i)), images[i]);
  }
}

// Decodes our own pattern sequence with `options` shown straight to the camera.
ImportOptions ProjectorOptions(ImportLayout layout, int width, int height) {
  ImportOptions options;
  options.layout = layout;
  options.projector_width = width;
  options.projector_height = height;
  return options;
}

// `images` written to scratch/capture (named by `name`), imported into scratch/frames.
ImportSummary WriteAndImport(const testing::ScratchDir& scratch, const std::vector<cv::Mat>& images,
                             const std::function<std::string(size_t)>& name,
                             const ImportOptions& options) {
  WriteImages(scratch.File("capture"), images, name);
  return ImportCapture(scratch.File("capture"), options, scratch.File("frames"));
}

CorrespondenceMap DecodeOwnPatterns(const PatternOptions& options) {
  FrameSet set;
  set.manifest =
      MakePatternManifest(options, options.projector_width, options.projector_height);
  for (const Pattern& pattern : GeneratePatterns(options)) set.images.push_back(pattern.image);
  set.Check();
  return Decode(set);
}

void ExpectSameCorrespondences(const CorrespondenceMap& ours, const CorrespondenceMap& theirs) {
  ASSERT_EQ(ours.mask.size(), theirs.mask.size());
  EXPECT_EQ(cv::norm(ours.mask, theirs.mask, cv::NORM_INF), 0.0);
  EXPECT_EQ(ours.step_x, theirs.step_x);
  EXPECT_EQ(ours.step_y, theirs.step_y);
  EXPECT_EQ(cv::norm(ours.proj_x, theirs.proj_x, cv::NORM_INF, ours.mask), 0.0);
  EXPECT_EQ(cv::norm(ours.proj_y, theirs.proj_y, cv::NORM_INF, ours.mask), 0.0);
}

// Every pixel decodes to its own column/row block centre (step = 2^omitted bits).
void ExpectGroundTruth(const CorrespondenceMap& map) {
  ASSERT_FALSE(map.mask.empty());
  EXPECT_EQ(map.CountValid(), map.mask.total());
  size_t wrong = 0;
  for (int y = 0; y < map.height(); ++y) {
    for (int x = 0; x < map.width(); ++x) {
      const float block_x = std::floor(x / map.step_x) * map.step_x + (map.step_x - 1) / 2;
      const float block_y = std::floor(y / map.step_y) * map.step_y + (map.step_y - 1) / 2;
      wrong += map.proj_x.at<float>(y, x) != block_x || map.proj_y.at<float>(y, x) != block_y;
    }
  }
  EXPECT_EQ(wrong, 0u);
}

// ---------------------------------------------------------------------------------------
// OpenCV GrayCodePattern.
// ---------------------------------------------------------------------------------------
class OpenCvImport : public ::testing::TestWithParam<cv::Size> {};

TEST_P(OpenCvImport, GeneratedSequenceDecodesLikeOurPatterns) {
  const cv::Size projector = GetParam();
  const testing::OpenCvGrayCodeSequence opencv = testing::GenerateOpenCvGrayCode(projector);
  ASSERT_FALSE(opencv.patterns.empty());
  const std::vector<cv::Mat> sequence = opencv.CaptureOrder();  // patterns, white, black
  const cv::Mat& white = opencv.white;
  // Unpadded numbers as OpenCV's sample and the statue capture name them (im1 … im44):
  // name order must put im10 after im9.
  testing::ScratchDir scratch;
  WriteImages(scratch.File("capture"), sequence,
              [](size_t i) { return fmt::format("pattern_cam1_im{}.png", i + 1); });
  // A second camera's images in the same folder, left out by --select.
  WriteImages(scratch.File("capture"), {white},
              [](size_t) { return std::string("pattern_cam2_im1.png"); });

  ImportOptions options;
  options.layout = ImportLayout::kOpenCvGrayCode;
  options.projector_width = projector.width;
  options.projector_height = projector.height;
  options.select = "pattern_cam1_*";
  const ImportSummary summary =
      ImportCapture(scratch.File("capture"), options, scratch.File("frames"));
  EXPECT_EQ(summary.images, sequence.size());
  EXPECT_EQ(summary.camera_width, projector.width);

  const FrameSet imported = LoadFrameSet(scratch.File("frames"));
  EXPECT_EQ(imported.manifest.frames.front().file, "pattern_cam1_im1.png");
  EXPECT_EQ(imported.manifest.frames[9].file, "pattern_cam1_im10.png");
  const CorrespondenceMap theirs = Decode(imported);
  PatternOptions own;
  own.projector_width = projector.width;
  own.projector_height = projector.height;
  const CorrespondenceMap ours = DecodeOwnPatterns(own);
  ExpectSameCorrespondences(ours, theirs);
  ExpectGroundTruth(theirs);

  // The generic order spec says the same thing.
  const int column_bits = BitsForSize(projector.width);
  const int row_bits = BitsForSize(projector.height);
  ImportOptions spec = options;
  spec.layout = ImportLayout::kOrder;
  spec.order = fmt::format("x{}-0+i, y{}-0+i, white, black", column_bits - 1, row_bits - 1);
  const std::vector<ImportedFrame> from_spec = LayoutFrames(spec);
  const std::vector<ImportedFrame> from_layout = LayoutFrames(options);
  ASSERT_EQ(from_spec.size(), from_layout.size());
  for (size_t i = 0; i < from_spec.size(); ++i) {
    EXPECT_EQ(from_spec[i].role, from_layout[i].role) << i;
    EXPECT_EQ(from_spec[i].axis, from_layout[i].axis) << i;
    EXPECT_EQ(from_spec[i].bit, from_layout[i].bit) << i;
    EXPECT_EQ(from_spec[i].bits, from_layout[i].bits) << i;
    EXPECT_EQ(from_spec[i].inverted, from_layout[i].inverted) << i;
  }
}

INSTANTIATE_TEST_SUITE_P(Projectors, OpenCvImport,
                         ::testing::Values(cv::Size(64, 48), cv::Size(100, 60)),
                         [](const ::testing::TestParamInfo<cv::Size>& info) {
                           return fmt::format("{}x{}", info.param.width, info.param.height);
                         });

TEST(OpenCvImport, ImageCountThatDoesNotFitIsOneClearError) {
  testing::ScratchDir scratch;
  const cv::Mat image(48, 64, CV_8UC1, cv::Scalar(128));
  WriteImages(scratch.File("capture"), std::vector<cv::Mat>(25, image),
              [](size_t i) { return fmt::format("im{:02}.png", i); });
  ImportOptions options;
  options.projector_width = 64;
  options.projector_height = 48;
  try {
    ImportCapture(scratch.File("capture"), options, scratch.File("frames"));
    FAIL() << "no error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("the layout expects 26 images"), std::string::npos)
        << e.what();
    EXPECT_NE(std::string(e.what()).find("has 25"), std::string::npos) << e.what();
  }
  EXPECT_FALSE(std::filesystem::exists(scratch.File("frames")));
}

TEST(OpenCvImport, MixedImageSizesAreRefused) {
  testing::ScratchDir scratch;
  std::vector<cv::Mat> images(26, cv::Mat(48, 64, CV_8UC1, cv::Scalar(128)));
  images[7] = cv::Mat(40, 64, CV_8UC1, cv::Scalar(128));
  WriteImages(scratch.File("capture"), images,
              [](size_t i) { return fmt::format("im{:02}.png", i); });
  ImportOptions options;
  options.projector_width = 64;
  options.projector_height = 48;
  try {
    ImportCapture(scratch.File("capture"), options, scratch.File("frames"));
    FAIL() << "no error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("im07.png: 64x40"), std::string::npos) << e.what();
  }
}

TEST(OrderSpec, ParsesTokensAndRefusesBadOnes) {
  const std::vector<ImportedFrame> frames =
      ParseOrderSpec("white,skip,x2-0,x0-2i,y1-0+i,phase:y:12.5:120,black", 8, 4,
                     PatternCode::kBinary);
  ASSERT_EQ(frames.size(), 2u + 3 + 3 + 4 + 1 + 1);
  EXPECT_EQ(frames[1].role, ImportedFrame::Role::kSkip);
  EXPECT_EQ(frames[2].bit, 2);
  EXPECT_EQ(frames[2].bits, 3);
  EXPECT_EQ(frames[2].code, PatternCode::kBinary);
  EXPECT_EQ(frames[4].bit, 0);
  EXPECT_EQ(frames[5].bit, 0);
  EXPECT_TRUE(frames[5].inverted);
  EXPECT_EQ(frames[7].bit, 2);
  EXPECT_EQ(frames[8].axis, PatternAxis::kY);
  EXPECT_FALSE(frames[8].inverted);
  EXPECT_TRUE(frames[9].inverted);
  EXPECT_EQ(frames[12].role, ImportedFrame::Role::kPhase);
  EXPECT_DOUBLE_EQ(frames[12].period_px, 12.5);
  EXPECT_NEAR(frames[12].shift_rad, 2.0 * kPi / 3.0, 1e-12);
  EXPECT_EQ(frames[13].role, ImportedFrame::Role::kBlack);

  for (const char* bad : {"x3", "z1", "x1,,white", "phase:x:0:0", "phase:x:10", "xa", "x1j"}) {
    SCOPED_TRACE(bad);
    EXPECT_THROW(ParseOrderSpec(bad, 8, 4, PatternCode::kGray), Error);
  }
  try {
    ParseOrderSpec("white,x3", 8, 4, PatternCode::kGray);
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("'x3'"), std::string::npos) << e.what();
  }
}

TEST(NameOrder, DigitRunsCompareAsNumbers) {
  std::vector<std::string> names = {"im10.png", "im2.png", "im1.png", "DSC04089.JPG",
                                    "DSC04052.JPG", "graycode_09.png", "graycode_10.png",
                                    "im02.png"};
  std::sort(names.begin(), names.end(), NaturalLess);
  const std::vector<std::string> expected = {"DSC04052.JPG", "DSC04089.JPG", "graycode_09.png",
                                             "graycode_10.png", "im1.png", "im02.png",
                                             "im2.png", "im10.png"};
  EXPECT_EQ(names, expected);
}

// ---------------------------------------------------------------------------------------
// SLStudio. The encoders' formulas, as in its source:
//   Gray (CodecGrayCode.cpp): patterns[0] on, [1] off; then for p < Nhorz = 10 the column
//   pattern amp = get_bit(binaryToGray(j), NbitsHorz − p) (get_bit is 1-based), rows likewise
//   with Nvert = 6.
//   2x3 (CodecPhaseShift2x3.cpp): per axis, 3 × computePhaseVector(size, 2π/3·i,
//   size/nPhases) then 3 × (…, size) with nPhases = 16; computePhaseVector writes
//   255·½(1 + cos(2π·i/pitch − phase)) into a uchar (truncation).
// ---------------------------------------------------------------------------------------
std::vector<cv::Mat> SlStudioGrayCode(int width, int height) {
  const int bits_x = static_cast<int>(std::ceil(std::log2(width)));
  const int bits_y = static_cast<int>(std::ceil(std::log2(height)));
  const auto get_bit = [](unsigned value, int n) { return (value & (1u << (n - 1))) ? 1 : 0; };
  std::vector<cv::Mat> patterns = {cv::Mat(height, width, CV_8UC1, cv::Scalar(255)),
                                   cv::Mat(height, width, CV_8UC1, cv::Scalar(0))};
  for (int p = 0; p < 10; ++p) {
    cv::Mat pattern(height, width, CV_8UC1);
    for (int j = 0; j < width; ++j) {
      pattern.col(j).setTo(255 * get_bit(GrayFromBinary(j), bits_x - p));
    }
    patterns.push_back(pattern);
  }
  for (int p = 0; p < 6; ++p) {
    cv::Mat pattern(height, width, CV_8UC1);
    for (int i = 0; i < height; ++i) {
      pattern.row(i).setTo(255 * get_bit(GrayFromBinary(i), bits_y - p));
    }
    patterns.push_back(pattern);
  }
  return patterns;
}

cv::Mat SlStudioPhaseVector(int width, int height, bool columns, float phase, float pitch) {
  const float pi = static_cast<float>(kPi);
  cv::Mat pattern(height, width, CV_8UC1);
  const int length = columns ? width : height;
  for (int i = 0; i < length; ++i) {
    const float amp = 0.5f * (1 + std::cos(2 * pi * i / pitch - phase));
    const uint8_t value = static_cast<uint8_t>(255.0f * amp);
    if (columns) {
      pattern.col(i).setTo(value);
    } else {
      pattern.row(i).setTo(value);
    }
  }
  return pattern;
}

std::vector<cv::Mat> SlStudioTwoByThree(int width, int height) {
  std::vector<cv::Mat> patterns;
  const float pi = static_cast<float>(kPi);
  for (bool columns : {true, false}) {
    const int size = columns ? width : height;
    for (float pitch : {static_cast<float>(size) / 16.0f, static_cast<float>(size)}) {
      for (int i = 0; i < 3; ++i) {
        patterns.push_back(SlStudioPhaseVector(width, height, columns, 2.0f * pi / 3.0f * i,
                                               pitch));
      }
    }
  }
  return patterns;
}

TEST(SlStudioImport, GrayCodeSequenceDecodesLikeOurPatterns) {
  // ≥ 10 column bits and ≥ 6 row bits, as SLStudio's codec needs: 11 and 7 here, so SLStudio
  // leaves out one low bit on each axis (step 2).
  const int width = 1100, height = 70;
  testing::ScratchDir scratch;
  ImportOptions options = ProjectorOptions(ImportLayout::kSlStudioGrayCode, width, height);
  WriteAndImport(scratch, SlStudioGrayCode(width, height),
                 [](size_t i) { return fmt::format("frame{}.bmp", i); }, options);
  const CorrespondenceMap theirs = Decode(LoadFrameSet(scratch.File("frames")));
  PatternOptions own;
  own.projector_width = width;
  own.projector_height = height;
  own.inverted = false;
  own.skip_low_bits = 1;
  ExpectSameCorrespondences(DecodeOwnPatterns(own), theirs);
  EXPECT_EQ(theirs.step_x, 2.0f);
  ExpectGroundTruth(theirs);

  // SLStudio's codec cannot serve a projector with fewer bits than it projects.
  options.projector_width = 1024;  // 10 bits: all projected
  EXPECT_EQ(LayoutFrames(options).size(), 18u);
  options.projector_width = 512;  // 9 bits
  EXPECT_THROW(LayoutFrames(options), Error);
}

// The phase of pixel u from frames I_k = A + B·cos(φ − s_k) with equally spaced shifts:
// φ = atan2(Σ I_k sin s_k, Σ I_k cos s_k) (the N-step formula; DESIGN.md's role `phase`).
double ReferencePhase(const std::vector<double>& intensities, const std::vector<double>& shifts) {
  double s = 0.0, c = 0.0;
  for (size_t k = 0; k < shifts.size(); ++k) {
    s += intensities[k] * std::sin(shifts[k]);
    c += intensities[k] * std::cos(shifts[k]);
  }
  return std::atan2(s, c);
}

double Wrap(double phase) {
  const double wrapped = std::fmod(phase, 2.0 * kPi);
  return wrapped < 0.0 ? wrapped + 2.0 * kPi : wrapped;
}

// Reads an imported phase set's frames.json and images; checks every image against the
// contract's I(u) = ½(1 + cos(2πu/period − shift)) · 255 (within SLStudio's truncation to
// uchar) and returns, per axis, the coordinate the contract's groups give: absolute from the
// coarsest group, refined by each finer one.
std::map<std::string, cv::Mat> DecodePhaseByContract(const std::string& directory, int width,
                                                      int height) {
  const nlohmann::json root =
      nlohmann::json::parse(ReadFileToString(JoinPath(directory, "frames.json"), "manifest"));
  EXPECT_EQ(root["format"], "sope-frames/1");
  EXPECT_EQ(root["projector"]["width"], width);
  // axis → period → (shift, image)
  std::map<std::string, std::map<double, std::vector<std::pair<double, cv::Mat>>>> groups;
  for (const nlohmann::json& frame : root["frames"]) {
    EXPECT_EQ(frame["role"], "phase");
    const std::string axis = frame["axis"];
    const double period = frame["period"], shift = frame["shift"];
    const cv::Mat image = ReadImage(JoinPath(directory, frame["file"]), cv::IMREAD_GRAYSCALE);
    double worst = 0.0;
    for (int v = 0; v < height; ++v) {
      for (int u = 0; u < width; ++u) {
        const double coordinate = axis == "x" ? u : v;
        const double expected =
            255.0 * 0.5 * (1.0 + std::cos(2.0 * kPi * coordinate / period - shift));
        worst = std::max(worst, std::abs(image.at<uint8_t>(v, u) - expected));
      }
    }
    EXPECT_LE(worst, 1.0) << frame["file"] << ": the image is not the pattern frames.json "
                          << "describes";
    groups[axis][period].emplace_back(shift, image);
  }
  std::map<std::string, cv::Mat> coordinates;
  for (const auto& [axis, by_period] : groups) {
    cv::Mat coordinate(height, width, CV_64FC1);
    for (int v = 0; v < height; ++v) {
      for (int u = 0; u < width; ++u) {
        double estimate = 0.0;
        bool first = true;
        for (auto it = by_period.rbegin(); it != by_period.rend(); ++it) {  // coarse first
          std::vector<double> intensities, shifts;
          for (const auto& [shift, image] : it->second) {
            intensities.push_back(image.at<uint8_t>(v, u));
            shifts.push_back(shift);
          }
          const double fraction = Wrap(ReferencePhase(intensities, shifts)) / (2.0 * kPi);
          const double period = it->first;
          if (first) {
            estimate = fraction * period;
            first = false;
          } else {
            estimate = (std::round(estimate / period - fraction) + fraction) * period;
          }
        }
        coordinate.at<double>(v, u) = estimate;
      }
    }
    coordinates[axis] = coordinate;
  }
  return coordinates;
}

TEST(SlStudioImport, TwoByThreePhaseManifestDescribesSlStudiosPatterns) {
  // DESIGN.md's example: a 1824-wide projector's x groups at periods 114 and 1824.
  const int width = 1824, height = 64;
  testing::ScratchDir scratch;
  const ImportOptions options =
      ProjectorOptions(ImportLayout::kSlStudioPhaseShift2x3, width, height);
  const ImportSummary summary =
      WriteAndImport(scratch, SlStudioTwoByThree(width, height),
                     [](size_t i) { return fmt::format("{:02}.png", i); }, options);
  EXPECT_TRUE(summary.has_phase);
  EXPECT_EQ(summary.images, 12u);
  const nlohmann::json root = nlohmann::json::parse(
      ReadFileToString(scratch.File("frames/frames.json"), "manifest"));
  EXPECT_EQ(root["frames"][0]["period"], 114.0);
  EXPECT_EQ(root["frames"][3]["period"], 1824.0);
  EXPECT_NEAR(root["frames"][1]["shift"].get<double>(), 2.0 * kPi / 3.0, 1e-12);
  EXPECT_EQ(root["frames"][6]["axis"], "y");
  EXPECT_EQ(root["frames"][6]["period"], 4.0);

  const std::map<std::string, cv::Mat> coordinates =
      DecodePhaseByContract(scratch.File("frames"), width, height);
  ASSERT_EQ(coordinates.size(), 2u);
  // Projector coordinates to within the 8-bit quantisation of the sinusoids (≤ 1 grey level
  // of 255 ≈ 0.2 % of a period: 0.25 px at period 114; the 4-px row period: 0.02 px).
  double worst_x = 0.0, worst_y = 0.0;
  for (int v = 0; v < height; ++v) {
    for (int u = 0; u < width; ++u) {
      worst_x = std::max(worst_x, std::abs(coordinates.at("x").at<double>(v, u) - u));
      worst_y = std::max(worst_y, std::abs(coordinates.at("y").at<double>(v, u) - v));
    }
  }
  EXPECT_LT(worst_x, 0.5);
  EXPECT_LT(worst_y, 0.5);

  // sope's phase decoder (Decode → DecodePhase) reads the imported set to the same
  // projector coordinates (camera = projector here): every pixel, within the same 8-bit
  // quantisation bound.
  const CorrespondenceMap decoded = Decode(LoadFrameSet(scratch.File("frames")));
  ASSERT_TRUE(decoded.HasX() && decoded.HasY());
  ASSERT_EQ(decoded.mask.size(), cv::Size(width, height));
  double decoded_x = 0.0, decoded_y = 0.0;
  size_t valid = 0;
  for (int v = 0; v < height; ++v) {
    for (int u = 0; u < width; ++u) {
      if (decoded.mask.at<uint8_t>(v, u) == 0) continue;
      ++valid;
      decoded_x = std::max(decoded_x, std::abs(double{decoded.proj_x.at<float>(v, u)} - u));
      decoded_y = std::max(decoded_y, std::abs(double{decoded.proj_y.at<float>(v, u)} - v));
    }
  }
  EXPECT_EQ(valid, static_cast<size_t>(width) * height);
  EXPECT_LT(decoded_x, 0.5);
  EXPECT_LT(decoded_y, 0.5);

  // One image missing: one clear error.
  std::filesystem::remove(scratch.File("capture/11.png"));
  EXPECT_THROW(ImportCapture(scratch.File("capture"), options, scratch.File("frames2")), Error);
}

TEST(SlStudioImport, ThreeStepAndCalibrationSequences) {
  ImportOptions options;
  options.projector_width = 912;
  options.projector_height = 570;
  options.layout = ImportLayout::kSlStudioPhaseShift3;
  const std::vector<ImportedFrame> three = LayoutFrames(options);
  ASSERT_EQ(three.size(), 3u);
  for (int i = 0; i < 3; ++i) {
    EXPECT_EQ(three[i].role, ImportedFrame::Role::kPhase);
    EXPECT_EQ(three[i].axis, PatternAxis::kX);
    EXPECT_EQ(three[i].period_px, 912.0);
    EXPECT_NEAR(three[i].shift_rad, 2.0 * kPi / 3.0 * i, 1e-12);
  }
  // The 3-step sequence decodes absolutely (a single group of period W).
  const int width = 912, height = 8;
  testing::ScratchDir scratch;
  std::vector<cv::Mat> images;
  for (int i = 0; i < 3; ++i) {
    images.push_back(SlStudioPhaseVector(width, height, true, 2.0f * static_cast<float>(kPi) /
                                                                  3.0f * i, width));
  }
  WriteImages(scratch.File("capture"), images, [](size_t i) { return fmt::format("{}.png", i); });
  options.projector_height = height;
  ImportCapture(scratch.File("capture"), options, scratch.File("frames"));
  const cv::Mat x = DecodePhaseByContract(scratch.File("frames"), width, height).at("x");
  double worst = 0.0;
  for (int u = 0; u < width; ++u) worst = std::max(worst, std::abs(x.at<double>(0, u) - u));
  EXPECT_LT(worst, 2.0);  // one grey level of 255 at period 912: ≤ 912/(2π·127) ≈ 1.1 px

  // The calibration codec is the 2x3 sequence on both axes, whatever --axes says.
  options.layout = ImportLayout::kSlStudioCalibration;
  options.axes = PatternAxes::kX;
  options.projector_height = 570;
  const std::vector<ImportedFrame> calibration = LayoutFrames(options);
  ASSERT_EQ(calibration.size(), 12u);
  EXPECT_DOUBLE_EQ(calibration[0].period_px, 912.0 / 16.0);
  EXPECT_DOUBLE_EQ(calibration[9].period_px, 570.0);
  options.layout = ImportLayout::kSlStudioPhaseShift2x3;
  EXPECT_EQ(LayoutFrames(options).size(), 6u);
}

// ---------------------------------------------------------------------------------------
// Foreign calibrations.
// ---------------------------------------------------------------------------------------
void WriteProcam(const std::string& path, const RigCalibration& rig, double units_per_metre,
                 const std::string& skip_key = "") {
  // As procam-calibration's calibrate.py writes it (cv2.FileStorage, XML by its name).
  cv::FileStorage fs(path, cv::FileStorage::WRITE);
  cv::Mat camera, projector, rotation, translation;
  cv::eigen2cv(rig.camera.matrix, camera);
  cv::eigen2cv(rig.projector.matrix, projector);
  cv::eigen2cv(rig.proj_from_cam.rotation, rotation);
  cv::eigen2cv(Eigen::Vector3d(rig.proj_from_cam.translation * units_per_metre), translation);
  const auto write = [&](const std::string& key, const cv::Mat& value) {
    if (key != skip_key) fs << key << value;
  };
  write("img_shape", (cv::Mat_<double>(2, 1) << rig.camera.height, rig.camera.width));
  if (skip_key != "rms") fs << "rms" << 0.42;
  write("cam_int", camera);
  write("cam_dist", cv::Mat(rig.camera.distortion, true).reshape(1, 1));
  write("proj_int", projector);
  write("proj_dist", cv::Mat(rig.projector.distortion, true).reshape(1, 1));
  write("roration", rotation);
  write("translation", translation);
}

void WriteSlStudio(const std::string& path, const RigCalibration& rig, double units_per_metre,
                   const std::string& skip_key = "") {
  // As SLStudio's CalibrationData::saveXML writes it.
  cv::FileStorage fs(path, cv::FileStorage::WRITE);
  cv::Mat camera, projector, rotation, translation;
  cv::eigen2cv(rig.camera.matrix, camera);
  cv::eigen2cv(rig.projector.matrix, projector);
  cv::eigen2cv(rig.proj_from_cam.rotation, rotation);
  cv::eigen2cv(Eigen::Vector3d(rig.proj_from_cam.translation * units_per_metre), translation);
  const auto write = [&](const std::string& key, const auto& value) {
    if (key != skip_key) fs << key << value;
  };
  write("Kc", cv::Mat_<float>(camera));
  write("kc", cv::Mat_<float>(cv::Mat(rig.camera.distortion, true)));
  write("Kp", cv::Mat_<float>(projector));
  write("kp", cv::Mat_<float>(cv::Mat(rig.projector.distortion, true)));
  write("Rp", cv::Mat_<float>(rotation));
  write("Tp", cv::Mat_<float>(translation));
  write("cam_error", 0.1);
  write("proj_error", 0.2);
  write("stereo_error", 0.3);
  write("frameWidth", rig.camera.width);
  write("frameHeight", rig.camera.height);
  write("screenResX", rig.projector.width);
  write("screenResY", rig.projector.height);
}

void ExpectSameRig(const RigCalibration& read, const RigCalibration& truth, double tolerance) {
  EXPECT_EQ(read.camera.width, truth.camera.width);
  EXPECT_EQ(read.camera.height, truth.camera.height);
  EXPECT_EQ(read.projector.width, truth.projector.width);
  EXPECT_EQ(read.projector.height, truth.projector.height);
  EXPECT_LT((read.camera.matrix - truth.camera.matrix).norm(),
            tolerance * truth.camera.matrix.norm());
  EXPECT_LT((read.projector.matrix - truth.projector.matrix).norm(),
            tolerance * truth.projector.matrix.norm());
  ASSERT_EQ(read.camera.distortion.size(), truth.camera.distortion.size());
  for (size_t i = 0; i < truth.camera.distortion.size(); ++i) {
    EXPECT_NEAR(read.camera.distortion[i], truth.camera.distortion[i], 1e-6);
  }
  EXPECT_LT((read.proj_from_cam.rotation - truth.proj_from_cam.rotation).norm(), 1e-6);
  EXPECT_LT((read.proj_from_cam.translation - truth.proj_from_cam.translation).norm(),
            tolerance * truth.proj_from_cam.translation.norm());
}

TEST(ForeignCalibration, ProcamCalibrationResultInMillimetres) {
  RigCalibration truth = testing::SmallRig();
  testing::ScratchDir scratch;
  const std::string path = scratch.File("calibration_result.xml");
  WriteProcam(path, truth, 1000.0);
  const RigCalibration read =
      ReadForeignCalibration(path, ForeignCalibrationFormat::kProcam, LengthUnit::kMillimetre,
                             truth.projector.width, truth.projector.height);
  ExpectSameRig(read, truth, 1e-12);
  EXPECT_DOUBLE_EQ(read.rms_stereo_px, 0.42);
  // The same file read as metres is 1000 times too long: the unit is the caller's to state.
  const RigCalibration as_metres =
      ReadForeignCalibration(path, ForeignCalibrationFormat::kProcam, LengthUnit::kMetre,
                             truth.projector.width, truth.projector.height);
  EXPECT_NEAR(as_metres.BaselineLength(), 1000.0 * truth.BaselineLength(), 1e-9);
  // Without a projector size (the file has none) it is refused.
  EXPECT_THROW(ReadForeignCalibration(path, ForeignCalibrationFormat::kProcam,
                                      LengthUnit::kMillimetre),
               Error);
}

// The file OpenCV 4.6's YAML parser loops forever on (a second %YAML header; found by
// calibration_yaml_fuzz for sope's own calibration reader, which shares the opening) is
// refused here too.
TEST(ForeignCalibration, ASecondYamlHeaderIsRefused) {
  testing::ScratchDir scratch;
  const std::string path = scratch.File("calibration_result.yaml");
  WriteFileAtomic(path, "%YAML:1.0\n---%YAML:1\nc.0\n--a");
  EXPECT_THROW_WITH_MESSAGE(ReadForeignCalibration(path, ForeignCalibrationFormat::kProcam,
                                                   LengthUnit::kMillimetre, 640, 480),
                            Error, "calibration_result.yaml", "%YAML directive");
}

TEST(ForeignCalibration, SlStudioCalibrationXml) {
  const RigCalibration truth = testing::SmallRig();
  testing::ScratchDir scratch;
  const std::string path = scratch.File("calibration.xml");
  WriteSlStudio(path, truth, 1000.0);
  const RigCalibration read = ReadForeignCalibration(path, ForeignCalibrationFormat::kSlStudio,
                                                     LengthUnit::kMillimetre);
  ExpectSameRig(read, truth, 1e-6);  // SLStudio stores floats
  EXPECT_NEAR(read.rms_projector_px, 0.2, 1e-12);
  // A projector size that contradicts screenResX/Y is refused.
  EXPECT_THROW(ReadForeignCalibration(path, ForeignCalibrationFormat::kSlStudio,
                                      LengthUnit::kMillimetre, 100, 100),
               Error);
}

TEST(ForeignCalibration, MissingKeyIsNamed) {
  const RigCalibration truth = testing::SmallRig();
  testing::ScratchDir scratch;
  for (const std::string key : {"Kp", "Tp", "screenResY"}) {
    const std::string path = scratch.File("slstudio_" + key + ".xml");
    WriteSlStudio(path, truth, 1000.0, key);
    try {
      ReadForeignCalibration(path, ForeignCalibrationFormat::kSlStudio, LengthUnit::kMillimetre);
      ADD_FAILURE() << key << ": no error";
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find("missing key '" + key + "'"), std::string::npos)
          << e.what();
    }
  }
  for (const std::string key : {"proj_int", "roration", "img_shape"}) {
    const std::string path = scratch.File("procam_" + key + ".xml");
    WriteProcam(path, truth, 1000.0, key);
    try {
      ReadForeignCalibration(path, ForeignCalibrationFormat::kProcam, LengthUnit::kMillimetre,
                             truth.projector.width, truth.projector.height);
      ADD_FAILURE() << key << ": no error";
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find("missing key '" + key + "'"), std::string::npos)
          << e.what();
    }
  }
}

TEST(ForeignCalibration, ImportWritesOurCalibrationBesideTheFrames) {
  const RigCalibration truth = testing::SmallRig();
  testing::ScratchDir scratch;
  PatternOptions own;
  own.projector_width = truth.projector.width;
  own.projector_height = truth.projector.height;
  std::vector<cv::Mat> images;
  for (const Pattern& pattern : GeneratePatterns(own)) {
    cv::Mat camera_image;
    cv::resize(pattern.image, camera_image, cv::Size(truth.camera.width, truth.camera.height), 0,
               0, cv::INTER_NEAREST);
    images.push_back(camera_image);
  }
  WriteImages(scratch.File("capture"), images, [](size_t i) { return fmt::format("{}.png", i); });
  WriteProcam(scratch.File("calibration_result.xml"), truth, 1000.0);
  ImportOptions options;
  options.layout = ImportLayout::kOrder;
  options.projector_width = truth.projector.width;
  options.projector_height = truth.projector.height;
  // GeneratePatterns' own order: white, black, then per axis MSB first, pattern + inverse.
  options.order = fmt::format("white,black,x{}-0+i,y{}-0+i", BitsForSize(own.projector_width) - 1,
                              BitsForSize(own.projector_height) - 1);
  const RigCalibration calibration = ReadForeignCalibration(
      scratch.File("calibration_result.xml"), ForeignCalibrationFormat::kProcam,
      LengthUnit::kMillimetre, truth.projector.width, truth.projector.height);
  const ImportSummary summary =
      ImportCapture(scratch.File("capture"), options, scratch.File("frames"), calibration);
  EXPECT_TRUE(summary.has_calibration);
  const FrameSetManifest manifest = ReadFrameSetManifest(scratch.File("frames"));
  EXPECT_EQ(manifest.calibration, "calibration.yaml");
  ExpectSameRig(ReadRigCalibration(scratch.File("frames/calibration.yaml")), truth, 1e-12);
  // A calibration of another camera size is refused.
  RigCalibration other = calibration;
  other.camera.width += 2;
  EXPECT_THROW(ImportCapture(scratch.File("capture"), options, scratch.File("frames2"), other),
               Error);
}

}  // namespace
}  // namespace sope
