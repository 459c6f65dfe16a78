#include "capture/foreign_calibration.h"

#include <cmath>

#include <opencv2/core.hpp>
#include <opencv2/core/eigen.hpp>

#include "core/error.h"
#include "core/file_util.h"

namespace sope {
namespace {

// `key` as a matrix of `rows`×`cols` doubles (rows < 0: any shape with `cols` elements).
cv::Mat Matrix(const cv::FileStorage& fs, const std::string& key, const std::string& where,
               int rows, int cols) {
  const cv::FileNode node = fs[key];
  SOPE_CHECK(!node.empty(), "calibration {}: missing key '{}'", where, key);
  cv::Mat matrix;
  try {
    if (node.isSeq()) {
      std::vector<double> values;
      node >> values;
      matrix = cv::Mat(values, true);
    } else {
      node >> matrix;
    }
  } catch (const cv::Exception&) {
    matrix.release();
  }
  SOPE_CHECK(!matrix.empty(), "calibration {}: '{}' is not a matrix", where, key);
  matrix.convertTo(matrix, CV_64F);
  if (rows > 0) {
    SOPE_CHECK(matrix.rows == rows && matrix.cols == cols,
               "calibration {}: '{}' must be {}x{}, got {}x{}", where, key, rows, cols,
               matrix.rows, matrix.cols);
  } else {
    SOPE_CHECK(static_cast<int>(matrix.total()) == cols,
               "calibration {}: '{}' must have {} elements, got {}", where, key, cols,
               matrix.total());
    matrix = matrix.reshape(1, cols);
  }
  SOPE_CHECK(cv::checkRange(matrix), "calibration {}: '{}' is not finite", where, key);
  return matrix;
}

std::vector<double> Distortion(const cv::FileStorage& fs, const std::string& key,
                               const std::string& where) {
  const cv::FileNode node = fs[key];
  SOPE_CHECK(!node.empty(), "calibration {}: missing key '{}'", where, key);
  cv::Mat matrix;
  try {
    node >> matrix;
  } catch (const cv::Exception&) {
    matrix.release();
  }
  SOPE_CHECK(!matrix.empty() && (matrix.rows == 1 || matrix.cols == 1),
             "calibration {}: '{}' is not a vector", where, key);
  matrix.convertTo(matrix, CV_64F);
  std::vector<double> values(matrix.begin<double>(), matrix.end<double>());
  // OpenCV returns 5, 8, 12 or 14 coefficients; our model takes up to 8 (k1 k2 p1 p2 k3 k4
  // k5 k6). Thin-prism / tilt terms must be zero to drop them.
  if (values.size() > 8) {
    for (size_t i = 8; i < values.size(); ++i) {
      SOPE_CHECK(values[i] == 0.0, "calibration {}: '{}' uses thin-prism/tilt coefficients, "
                 "which sope's lens model does not have", where, key);
    }
    values.resize(8);
  }
  return values;
}

double Number(const cv::FileStorage& fs, const std::string& key, const std::string& where,
              bool required) {
  const cv::FileNode node = fs[key];
  if (node.empty() && !required) return 0.0;
  SOPE_CHECK(!node.empty(), "calibration {}: missing key '{}'", where, key);
  SOPE_CHECK(node.isInt() || node.isReal(), "calibration {}: '{}' is not a number", where, key);
  return static_cast<double>(node);
}

int Size(double value, const std::string& key, const std::string& where) {
  SOPE_CHECK(value > 0 && value == std::floor(value) && value < 1e6,
             "calibration {}: '{}' must be a positive integer, got {}", where, key, value);
  return static_cast<int>(value);
}

}  // namespace

std::string ToString(ForeignCalibrationFormat format) {
  return format == ForeignCalibrationFormat::kProcam ? "procam" : "slstudio";
}

ForeignCalibrationFormat ForeignCalibrationFormatFromString(const std::string& text) {
  if (text == "procam") return ForeignCalibrationFormat::kProcam;
  if (text == "slstudio") return ForeignCalibrationFormat::kSlStudio;
  SOPE_THROW("unknown calibration format '{}' (expected procam or slstudio)", text);
}

std::string ToString(LengthUnit unit) {
  switch (unit) {
    case LengthUnit::kMillimetre: return "mm";
    case LengthUnit::kCentimetre: return "cm";
    case LengthUnit::kMetre: return "m";
  }
  return "?";
}

LengthUnit LengthUnitFromString(const std::string& text) {
  if (text == "mm") return LengthUnit::kMillimetre;
  if (text == "cm") return LengthUnit::kCentimetre;
  if (text == "m") return LengthUnit::kMetre;
  SOPE_THROW("unknown length unit '{}' (expected mm, cm or m)", text);
}

double MetresPer(LengthUnit unit) {
  switch (unit) {
    case LengthUnit::kMillimetre: return 1e-3;
    case LengthUnit::kCentimetre: return 1e-2;
    case LengthUnit::kMetre: return 1.0;
  }
  return 1.0;
}

RigCalibration ReadForeignCalibration(const std::string& path, ForeignCalibrationFormat format,
                                      LengthUnit unit, int projector_width,
                                      int projector_height) {
  const std::string where = fmt::format("{} ({})", path, ToString(format));
  cv::FileStorage fs;
  OpenFileStorageForReading(path, ToString(format) + " calibration", &fs);

  RigCalibration calibration;
  cv::Mat rotation, translation;
  if (format == ForeignCalibrationFormat::kProcam) {
    const cv::Mat shape = Matrix(fs, "img_shape", where, -1, 2);  // (rows, cols)
    calibration.camera.height = Size(shape.at<double>(0), "img_shape", where);
    calibration.camera.width = Size(shape.at<double>(1), "img_shape", where);
    cv::cv2eigen(Matrix(fs, "cam_int", where, 3, 3), calibration.camera.matrix);
    calibration.camera.distortion = Distortion(fs, "cam_dist", where);
    cv::cv2eigen(Matrix(fs, "proj_int", where, 3, 3), calibration.projector.matrix);
    calibration.projector.distortion = Distortion(fs, "proj_dist", where);
    const char* rotation_key = fs["roration"].empty() && !fs["rotation"].empty() ? "rotation"
                                                                                 : "roration";
    rotation = Matrix(fs, rotation_key, where, 3, 3);
    translation = Matrix(fs, "translation", where, -1, 3);
    calibration.rms_stereo_px = Number(fs, "rms", where, false);
    SOPE_CHECK(projector_width > 0 && projector_height > 0,
               "calibration {}: the file has no projector size; give it (--projector WxH)",
               where);
    calibration.projector.width = projector_width;
    calibration.projector.height = projector_height;
  } else {
    cv::cv2eigen(Matrix(fs, "Kc", where, 3, 3), calibration.camera.matrix);
    calibration.camera.distortion = Distortion(fs, "kc", where);
    cv::cv2eigen(Matrix(fs, "Kp", where, 3, 3), calibration.projector.matrix);
    calibration.projector.distortion = Distortion(fs, "kp", where);
    rotation = Matrix(fs, "Rp", where, 3, 3);
    translation = Matrix(fs, "Tp", where, -1, 3);
    calibration.camera.width = Size(Number(fs, "frameWidth", where, true), "frameWidth", where);
    calibration.camera.height =
        Size(Number(fs, "frameHeight", where, true), "frameHeight", where);
    calibration.projector.width =
        Size(Number(fs, "screenResX", where, true), "screenResX", where);
    calibration.projector.height =
        Size(Number(fs, "screenResY", where, true), "screenResY", where);
    SOPE_CHECK((projector_width <= 0 && projector_height <= 0) ||
                   (projector_width == calibration.projector.width &&
                    projector_height == calibration.projector.height),
               "calibration {}: projector {}x{} (screenResX/Y) differs from the given {}x{}",
               where, calibration.projector.width, calibration.projector.height,
               projector_width, projector_height);
    calibration.rms_camera_px = Number(fs, "cam_error", where, false);
    calibration.rms_projector_px = Number(fs, "proj_error", where, false);
    calibration.rms_stereo_px = Number(fs, "stereo_error", where, false);
  }
  cv::cv2eigen(rotation, calibration.proj_from_cam.rotation);
  cv::cv2eigen(translation, calibration.proj_from_cam.translation);
  calibration.proj_from_cam.translation *= MetresPer(unit);
  try {
    calibration.Check();
  } catch (const Error& e) {
    SOPE_THROW("calibration {}: {}", where, e.what());
  }
  return calibration;
}

}  // namespace sope
