// JSON of the contract types (DESIGN.md "Recognition result", gt_pose.json, the
// calibration report, results.jsonl): one writer and one reader per type, so every file
// spells a pose the same way. Only the forward declarations of nlohmann::json here; the
// .cc files that build JSON include <nlohmann/json.hpp> themselves.
#pragma once

#include <string>

#include <Eigen/Core>
#include <nlohmann/json_fwd.hpp>

#include "core/rigid3d.h"

namespace sope {

// A number, or null when it is not finite (NaN, ±inf: JSON has no such numbers).
nlohmann::json JsonNumber(double value);

// [x, y, z].
nlohmann::json Vector3dToJson(const Eigen::Vector3d& v);
// A 3×3 matrix as three rows [[r00, r01, r02], [r10, …], …].
nlohmann::json Matrix3dToJson(const Eigen::Matrix3d& m);
// {"rotation": 3×3 rows, "translation": [x, y, z] (metres)} of b_from_a.
nlohmann::json Rigid3dToJson(const Rigid3d& pose);

// The readers take `what` for the error message ("gt_pose.json objects[0].pose") and throw
// sope::Error naming it and the bad field: missing keys, wrong shapes, non-numbers,
// non-finite values, or (Rigid3d) a rotation that is not orthonormal with det +1 within
// 1e-6.
Eigen::Vector3d Vector3dFromJson(const nlohmann::json& j, const std::string& what);
Eigen::Matrix3d Matrix3dFromJson(const nlohmann::json& j, const std::string& what);
Rigid3d Rigid3dFromJson(const nlohmann::json& j, const std::string& what);

}  // namespace sope
