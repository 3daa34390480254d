// Geometry that cannot be built is a configuration error naming the key (docs/model.md 5).
#include <gtest/gtest.h>

#include <string>

#include "tests/test_util.hpp"

namespace cvt {
namespace {

void expect_geometry_error(const std::vector<std::string>& overrides, const std::string& key,
                           const std::string& phrase) {
  try {
    (void)test::model("reference", overrides);
    ADD_FAILURE() << "no ConfigError for " << overrides.front();
  } catch (const ConfigError& e) {
    EXPECT_EQ(e.key(), key) << e.what();
    EXPECT_NE(std::string(e.what()).find(phrase), std::string::npos) << e.what();
    std::printf("%s -> %s\n", overrides.front().c_str(), e.what());
  }
}

TEST(BadGeometryTest, ChainTooShort) {
  expect_geometry_error({"chain.links=40"}, "chain.links", "too short");
}

TEST(BadGeometryTest, ChainTooLong) {
  expect_geometry_error({"chain.links=200"}, "chain.links", "too long");
}

TEST(BadGeometryTest, ImpossibleRatio) {
  expect_geometry_error({"geometry.ratio=10"}, "geometry.ratio", "impossible ratio");
}

}  // namespace
}  // namespace cvt
