#include "core/json.h"

#include <cmath>
#include <limits>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "core/error.h"

namespace sope {
namespace {

// Throws sope::Error whose message contains `needle`.
template <typename F>
void ExpectErrorNaming(F&& f, const std::string& needle) {
  try {
    f();
    ADD_FAILURE() << "no error; expected one naming '" << needle << "'";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find(needle), std::string::npos) << e.what();
  }
}

TEST(Json, Rigid3dRoundTripsExactlyInTheContractShape) {
  const Rigid3d pose(RotationFromEulerXYZ(0.3, -1.1, 2.0), Eigen::Vector3d(0.01, -0.2, 0.6));
  const nlohmann::json j = Rigid3dToJson(pose);
  // DESIGN.md "Recognition result": rotation as three rows, translation in metres.
  ASSERT_EQ(j.at("rotation").size(), 3u);
  for (int r = 0; r < 3; ++r) {
    ASSERT_EQ(j.at("rotation")[r].size(), 3u);
    for (int c = 0; c < 3; ++c) EXPECT_EQ(j.at("rotation")[r][c].get<double>(), pose.rotation(r, c));
  }
  EXPECT_EQ(j.at("translation")[2].get<double>(), 0.6);
  // Through text and back: the same doubles.
  const Rigid3d back = Rigid3dFromJson(nlohmann::json::parse(j.dump()), "pose");
  EXPECT_EQ(back.rotation, pose.rotation);
  EXPECT_EQ(back.translation, pose.translation);
}

TEST(Json, ReadersNameTheBadField) {
  nlohmann::json j = Rigid3dToJson(Rigid3d());
  j.erase("translation");
  ExpectErrorNaming([&] { Rigid3dFromJson(j, "gt_pose.json objects[0].pose"); },
                    "gt_pose.json objects[0].pose");
  j = Rigid3dToJson(Rigid3d());
  j["translation"] = {0.0, 1.0};
  ExpectErrorNaming([&] { Rigid3dFromJson(j, "pose"); }, "pose.translation");
  j = Rigid3dToJson(Rigid3d());
  j["rotation"][1][2] = "x";
  ExpectErrorNaming([&] { Rigid3dFromJson(j, "pose"); }, "pose.rotation");
  j = Rigid3dToJson(Rigid3d());
  j["rotation"][0][0] = 2.0;  // not orthonormal
  ExpectErrorNaming([&] { Rigid3dFromJson(j, "pose"); }, "not a rotation");
  j = Rigid3dToJson(Rigid3d(-Eigen::Matrix3d::Identity(), Eigen::Vector3d::Zero()));
  ExpectErrorNaming([&] { Rigid3dFromJson(j, "pose"); }, "not a rotation");  // det −1
  ExpectErrorNaming(
      [&] {
        Vector3dFromJson(nlohmann::json::array({1.0, 2.0, std::nan("")}), "gt_pose.json centre");
      },
      "gt_pose.json centre");
}

TEST(Json, NonFiniteNumbersAreNull) {
  EXPECT_TRUE(JsonNumber(std::numeric_limits<double>::quiet_NaN()).is_null());
  EXPECT_TRUE(JsonNumber(std::numeric_limits<double>::infinity()).is_null());
  EXPECT_EQ(JsonNumber(1.5).get<double>(), 1.5);
}

}  // namespace
}  // namespace sope
