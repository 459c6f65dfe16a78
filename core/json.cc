#include "core/json.h"

#include <cmath>

#include <nlohmann/json.hpp>

#include "core/error.h"

namespace sope {
namespace {

double FiniteNumber(const nlohmann::json& j, const std::string& what) {
  SOPE_CHECK(j.is_number(), "{}: expected a number, got {}", what, j.dump());
  const double value = j.get<double>();
  SOPE_CHECK(std::isfinite(value), "{}: {} is not finite", what, j.dump());
  return value;
}

}  // namespace

nlohmann::json JsonNumber(double value) {
  return std::isfinite(value) ? nlohmann::json(value) : nlohmann::json(nullptr);
}

nlohmann::json Vector3dToJson(const Eigen::Vector3d& v) { return {v.x(), v.y(), v.z()}; }

nlohmann::json Matrix3dToJson(const Eigen::Matrix3d& m) {
  nlohmann::json rows = nlohmann::json::array();
  for (int r = 0; r < 3; ++r) rows.push_back({m(r, 0), m(r, 1), m(r, 2)});
  return rows;
}

nlohmann::json Rigid3dToJson(const Rigid3d& pose) {
  return {{"rotation", Matrix3dToJson(pose.rotation)},
          {"translation", Vector3dToJson(pose.translation)}};
}

Eigen::Vector3d Vector3dFromJson(const nlohmann::json& j, const std::string& what) {
  SOPE_CHECK(j.is_array() && j.size() == 3, "{}: expected [x, y, z], got {}", what, j.dump());
  Eigen::Vector3d v;
  for (int i = 0; i < 3; ++i) v[i] = FiniteNumber(j[i], what);
  return v;
}

Eigen::Matrix3d Matrix3dFromJson(const nlohmann::json& j, const std::string& what) {
  SOPE_CHECK(j.is_array() && j.size() == 3, "{}: expected three rows of three numbers, got {}",
             what, j.dump());
  Eigen::Matrix3d m;
  for (int r = 0; r < 3; ++r) {
    SOPE_CHECK(j[r].is_array() && j[r].size() == 3,
               "{}: row {} must hold three numbers, got {}", what, r, j[r].dump());
    for (int c = 0; c < 3; ++c) m(r, c) = FiniteNumber(j[r][c], what);
  }
  return m;
}

Rigid3d Rigid3dFromJson(const nlohmann::json& j, const std::string& what) {
  SOPE_CHECK(j.is_object() && j.contains("rotation") && j.contains("translation"),
             "{}: expected {{\"rotation\": 3x3, \"translation\": [x, y, z]}}", what);
  Rigid3d pose;
  pose.rotation = Matrix3dFromJson(j.at("rotation"), what + ".rotation");
  pose.translation = Vector3dFromJson(j.at("translation"), what + ".translation");
  const double orthogonality =
      (pose.rotation * pose.rotation.transpose() - Eigen::Matrix3d::Identity()).norm();
  SOPE_CHECK(orthogonality < 1e-6 && pose.rotation.determinant() > 0,
             "{}.rotation is not a rotation (|R·Rᵀ − I| = {:.3g}, det {:.6f})", what,
             orthogonality, pose.rotation.determinant());
  return pose;
}

}  // namespace sope
