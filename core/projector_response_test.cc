#include "core/projector_response.h"

#include <cmath>

#include <gtest/gtest.h>

#include "core/error.h"
#include "tests/test_support.h"

namespace sope {
namespace {

TEST(ProjectorResponse, GammaTableInvertsAndApplies) {
  const ProjectorResponse response = ProjectorResponse::Gamma(2.2, 257);
  response.Check();
  for (double v = 0.0; v <= 1.0; v += 0.01) {
    EXPECT_NEAR(response.Apply(v), std::pow(v, 2.2), 2e-4) << v;
    EXPECT_NEAR(response.Apply(response.Invert(v)), v, 1e-9) << v;
  }
  const ProjectorResponse identity;
  EXPECT_TRUE(identity.IsIdentity());
  EXPECT_EQ(identity.Apply(0.3), 0.3);
  EXPECT_EQ(identity.Invert(0.7), 0.7);
}

TEST(ProjectorResponse, FromMeasuredNormalisesAndRejectsFlatCurves) {
  const ProjectorResponse response = ProjectorResponse::FromMeasured({20.0, 30.0, 29.0, 220.0});
  ASSERT_EQ(response.table.size(), 4u);
  EXPECT_DOUBLE_EQ(response.table[0], 0.0);
  EXPECT_DOUBLE_EQ(response.table[1], 0.05);
  EXPECT_DOUBLE_EQ(response.table[2], 0.05);  // made non-decreasing
  EXPECT_DOUBLE_EQ(response.table[3], 1.0);
  EXPECT_THROW_WITH_MESSAGE(ProjectorResponse::FromMeasured({50.0, 50.0}), Error, "no contrast");
  EXPECT_THROW_WITH_MESSAGE(ProjectorResponse::FromMeasured({50.0}), Error, "1 measured levels");
  ProjectorResponse bad;
  bad.table = {0.0, 0.6, 0.5, 1.0};
  EXPECT_THROW_WITH_MESSAGE(bad.Check(), Error, "entry 2 (0.5)", "must not decrease");
  bad.table = {0.1, 1.0};
  EXPECT_THROW_WITH_MESSAGE(bad.Check(), Error, "runs from 0.1 to 1");
  EXPECT_THROW_WITH_MESSAGE(ProjectorResponse::Gamma(0.0), Error, "projector gamma 0");
}

}  // namespace
}  // namespace sope
