#include "core/rig_calibration.h"

#include <cmath>

#include <opencv2/core.hpp>
#include <opencv2/core/eigen.hpp>

#include "core/error.h"
#include "core/file_util.h"

namespace sope {
namespace {

constexpr const char* kResponseKey = "projector_response";

cv::Mat ReadMatrix(const cv::FileStorage& fs, const std::string& key, const std::string& path,
                   int rows, int cols) {
  cv::Mat matrix;
  const cv::FileNode node = fs[key];
  SOPE_CHECK(!node.empty(), "calibration {}: missing key '{}'", path, key);
  if (node.isMap()) {
    // OpenCV allocates rows × cols before reading `data`: check the sizes first (the
    // largest matrix here is the projector response, a vector of up to 4096 entries).
    constexpr int kMaxSide = 4096;
    const cv::FileNode rows_node = node["rows"], cols_node = node["cols"];
    const cv::FileNode data_node = node["data"];
    SOPE_CHECK(rows_node.isInt() && cols_node.isInt() && data_node.isSeq(),
               "calibration {}: '{}' is not a matrix", path, key);
    const int rows_in_file = static_cast<int>(rows_node);
    const int cols_in_file = static_cast<int>(cols_node);
    SOPE_CHECK(rows_in_file >= 1 && rows_in_file <= kMaxSide && cols_in_file >= 1 &&
                   cols_in_file <= kMaxSide,
               "calibration {}: '{}' is {}x{}, expected sizes in 1..{}", path, key, rows_in_file,
               cols_in_file, kMaxSide);
    SOPE_CHECK(data_node.size() == static_cast<size_t>(rows_in_file) * cols_in_file,
               "calibration {}: '{}' is {}x{} but holds {} values", path, key, rows_in_file,
               cols_in_file, data_node.size());
  }
  try {
    node >> matrix;
  } catch (const cv::Exception&) {
    SOPE_THROW("calibration {}: '{}' is not a matrix", path, key);
  }
  SOPE_CHECK(!matrix.empty(), "calibration {}: '{}' is not a matrix", path, key);
  matrix.convertTo(matrix, CV_64F);
  if (rows > 0) {
    SOPE_CHECK(matrix.rows == rows && matrix.cols == cols,
               "calibration {}: '{}' must be {}x{}, got {}x{}", path, key, rows, cols,
               matrix.rows, matrix.cols);
  }
  return matrix;
}

int ReadPositiveInt(const cv::FileStorage& fs, const std::string& key, const std::string& path) {
  const cv::FileNode node = fs[key];
  SOPE_CHECK(!node.empty() && (node.isInt() || node.isReal()),
             "calibration {}: missing or non-numeric key '{}'", path, key);
  const double value = static_cast<double>(node);
  SOPE_CHECK(value > 0 && value == std::floor(value) && value < 1e6,
             "calibration {}: '{}' must be a positive integer, got {}", path, key, value);
  return static_cast<int>(value);
}

double ReadOptionalDouble(const cv::FileStorage& fs, const std::string& key) {
  const cv::FileNode node = fs[key];
  return (!node.empty() && (node.isReal() || node.isInt())) ? static_cast<double>(node) : 0.0;
}

CameraModel ReadDevice(const cv::FileStorage& fs, const std::string& prefix,
                       const std::string& path) {
  CameraModel model;
  model.width = ReadPositiveInt(fs, prefix + "_width", path);
  model.height = ReadPositiveInt(fs, prefix + "_height", path);
  cv::cv2eigen(ReadMatrix(fs, prefix + "_matrix", path, 3, 3), model.matrix);
  const cv::Mat distortion = ReadMatrix(fs, prefix + "_distortion", path, -1, -1);
  SOPE_CHECK(distortion.rows == 1 || distortion.cols == 1,
             "calibration {}: '{}_distortion' must be a vector", path, prefix);
  model.distortion.assign(distortion.begin<double>(), distortion.end<double>());
  try {
    model.Check();
  } catch (const Error& e) {
    SOPE_THROW("calibration {}: {}: {}", path, prefix, e.what());
  }
  return model;
}

void WriteDevice(cv::FileStorage& fs, const std::string& prefix, const CameraModel& model) {
  cv::Mat matrix;
  cv::eigen2cv(model.matrix, matrix);
  fs << prefix + "_width" << model.width << prefix + "_height" << model.height;
  fs << prefix + "_matrix" << matrix;
  std::vector<double> distortion = model.distortion;
  if (distortion.empty()) distortion.assign(5, 0.0);
  fs << prefix + "_distortion" << cv::Mat(distortion, true).reshape(1, 1);
}

}  // namespace

void RigCalibration::Check() const {
  camera.Check();
  projector.Check();
  const Eigen::Matrix3d& rotation = proj_from_cam.rotation;
  SOPE_CHECK(rotation.allFinite() && proj_from_cam.translation.allFinite(),
             "proj_from_cam is not finite");
  SOPE_CHECK((rotation.transpose() * rotation - Eigen::Matrix3d::Identity()).norm() < 1e-5 &&
                 std::abs(rotation.determinant() - 1.0) < 1e-5,
             "proj_from_cam_rotation is not a rotation matrix (det = {})",
             rotation.determinant());
}

double RigCalibration::BaselineLength() const {
  // Projector centre in camera coordinates: −Rᵀt.
  return proj_from_cam.translation.norm();
}

RigCalibration ReadRigCalibration(const std::string& path) {
  cv::FileStorage fs;
  OpenFileStorageForReading(path, "calibration", &fs);
  // Keys are looked up in the top-level map; OpenCV asserts (throws) on anything else.
  SOPE_CHECK(fs.root().isMap(), "calibration {}: not a calibration file (the top level is not a "
             "map of keys)", path);
  RigCalibration calibration;
  try {  // a later document of the stream that is no map makes lookups throw too
    calibration.camera = ReadDevice(fs, "camera", path);
    calibration.projector = ReadDevice(fs, "projector", path);
    cv::cv2eigen(ReadMatrix(fs, "proj_from_cam_rotation", path, 3, 3),
                 calibration.proj_from_cam.rotation);
    cv::Mat translation = ReadMatrix(fs, "proj_from_cam_translation", path, -1, -1);
    SOPE_CHECK(translation.total() == 3, "calibration {}: 'proj_from_cam_translation' must "
               "have 3 elements, got {}", path, translation.total());
    translation = translation.reshape(1, 3);
    cv::cv2eigen(translation, calibration.proj_from_cam.translation);
    calibration.rms_camera_px = ReadOptionalDouble(fs, "rms_camera_px");
    calibration.rms_projector_px = ReadOptionalDouble(fs, "rms_projector_px");
    calibration.rms_stereo_px = ReadOptionalDouble(fs, "rms_stereo_px");
    if (!fs[kResponseKey].empty()) {
      const cv::Mat response = ReadMatrix(fs, kResponseKey, path, -1, -1);
      SOPE_CHECK(response.rows == 1 || response.cols == 1,
                 "calibration {}: '{}' must be a vector", path, kResponseKey);
      calibration.projector_response.table.assign(response.begin<double>(), response.end<double>());
      try {
        calibration.projector_response.Check();
      } catch (const Error& e) {
        SOPE_THROW("calibration {}: {}", path, e.what());
      }
    }
  } catch (const Error&) {
    throw;
  } catch (const cv::Exception& e) {
    SOPE_THROW("calibration {}: not a calibration file (OpenCV: {})", path, e.err);
  } catch (const std::exception& e) {
    SOPE_THROW("calibration {}: not a calibration file ({})", path, e.what());
  }
  try {
    calibration.Check();
  } catch (const Error& e) {
    SOPE_THROW("calibration {}: {}", path, e.what());
  }
  return calibration;
}

void WriteRigCalibration(const std::string& path, const RigCalibration& calibration) {
  calibration.Check();
  cv::FileStorage fs(".yaml", cv::FileStorage::WRITE | cv::FileStorage::MEMORY);
  WriteDevice(fs, "camera", calibration.camera);
  WriteDevice(fs, "projector", calibration.projector);
  cv::Mat rotation, translation;
  cv::eigen2cv(calibration.proj_from_cam.rotation, rotation);
  cv::eigen2cv(calibration.proj_from_cam.translation, translation);
  fs << "proj_from_cam_rotation" << rotation;
  fs << "proj_from_cam_translation" << translation;
  fs << "rms_camera_px" << calibration.rms_camera_px;
  fs << "rms_projector_px" << calibration.rms_projector_px;
  fs << "rms_stereo_px" << calibration.rms_stereo_px;
  calibration.projector_response.Check();
  if (!calibration.projector_response.IsIdentity()) {
    fs << kResponseKey << cv::Mat(calibration.projector_response.table, true).reshape(1, 1);
  }
  WriteFileAtomic(path, fs.releaseAndGetString());
}

}  // namespace sope
