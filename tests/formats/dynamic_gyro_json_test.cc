// The `dynamic_gyro` block of an "imucal-params v1" document: exact round trip, a document
// without one unchanged byte for byte, and every malformed block refused with its JSON path.
#include "formats/dynamic_gyro_json.h"

#include <cmath>
#include <cstring>
#include <limits>
#include <random>
#include <string>

#include "core/params.h"
#include "formats/params_json.h"
#include "gtest/gtest.h"
#include "nlohmann/json.hpp"

namespace imucal::formats {
namespace {

using Json = nlohmann::ordered_json;
constexpr double kNan = std::numeric_limits<double>::quiet_NaN();
constexpr uint64_t kSeed = 27;

bool SameBits(double a, double b) { return std::memcmp(&a, &b, sizeof(double)) == 0; }

core::ParamSet StaticParams() {
  core::ParamSet p;
  p.device = "robot-27";
  p.gyro.bias = Eigen::Vector3d(0.01, -0.02, 0.003);
  p.gyro_calibrated = true;
  return p;
}

core::DynamicGyro RandomBlock(std::mt19937_64& rng, int taps, int dilation) {
  std::uniform_real_distribution<double> u(-1e-3, 1e-3);
  core::DynamicGyro b;
  b.rate_hz = 200.0;
  b.delay_s = 0.0026;
  b.delay_std_error_s = 1.1e-4;
  b.odd_rate = Eigen::Vector3d(u(rng), u(rng), u(rng));
  b.odd_rate_std_error = Eigen::Vector3d(1e-5, kNan, 2e-5);
  b.taps = taps;
  b.dilation = dilation;
  for (int i = 0; i < 18 * taps; ++i) b.weights.push_back(u(rng));
  b.ridge_lambda = 0.125;
  b.envelope.max_abs_rate_rad_s = Eigen::Vector3d(5.0, 6.0, 7.5);
  b.envelope.max_abs_accel_m_s2 = Eigen::Vector3d(20.0, 21.0, 30.0);
  b.training.push_back({"room1/imu.csv:room1/ref.csv", "ab12", 140.5, 1.6, 0.8});
  b.training.push_back({"room3", "cd34", 130.25, kNan, kNan});
  b.gate_reason = "learnt 0.8 deg against static 1.6 deg held out";
  return b;
}

// The JSON of a parameter set with `edit` applied to its dynamic_gyro member.
template <typename Edit>
std::string WithEditedBlock(Edit edit) {
  std::mt19937_64 rng(kSeed);
  core::ParamSet p = StaticParams();
  p.dynamic_gyro = RandomBlock(rng, 2, 3);
  Json j = Json::parse(ParamSetToJson(p));
  edit(j["dynamic_gyro"]);
  return j.dump(2);
}

TEST(DynamicGyroJsonTest, RoundTripIsExact) {
  std::mt19937_64 rng(kSeed);
  core::ParamSet p = StaticParams();
  p.dynamic_gyro = RandomBlock(rng, 29, 16);
  const std::string json = ParamSetToJson(p);
  absl::StatusOr<core::ParamSet> back = ParamSetFromJson(json);
  ASSERT_TRUE(back.ok()) << back.status();
  ASSERT_TRUE(back->dynamic_gyro.has_value());
  const core::DynamicGyro& a = *p.dynamic_gyro;
  const core::DynamicGyro& b = *back->dynamic_gyro;
  EXPECT_TRUE(SameBits(a.rate_hz, b.rate_hz));
  EXPECT_TRUE(SameBits(a.delay_s, b.delay_s));
  EXPECT_TRUE(SameBits(a.delay_std_error_s, b.delay_std_error_s));
  for (int i = 0; i < 3; ++i) {
    EXPECT_TRUE(SameBits(a.odd_rate(i), b.odd_rate(i)));
    EXPECT_TRUE(SameBits(a.odd_rate_std_error(i), b.odd_rate_std_error(i)));
    EXPECT_TRUE(SameBits(a.envelope.max_abs_rate_rad_s(i), b.envelope.max_abs_rate_rad_s(i)));
    EXPECT_TRUE(SameBits(a.envelope.max_abs_accel_m_s2(i), b.envelope.max_abs_accel_m_s2(i)));
  }
  EXPECT_EQ(a.taps, b.taps);
  EXPECT_EQ(a.dilation, b.dilation);
  ASSERT_EQ(a.weights.size(), b.weights.size());
  for (size_t i = 0; i < a.weights.size(); ++i) EXPECT_TRUE(SameBits(a.weights[i], b.weights[i]));
  EXPECT_TRUE(SameBits(a.ridge_lambda, b.ridge_lambda));
  ASSERT_EQ(a.training.size(), b.training.size());
  for (size_t i = 0; i < a.training.size(); ++i) {
    EXPECT_EQ(a.training[i].name, b.training[i].name);
    EXPECT_EQ(a.training[i].sha256, b.training[i].sha256);
    EXPECT_TRUE(SameBits(a.training[i].duration_s, b.training[i].duration_s));
    EXPECT_TRUE(SameBits(a.training[i].aoe_static_deg, b.training[i].aoe_static_deg));
    EXPECT_TRUE(SameBits(a.training[i].aoe_learnt_deg, b.training[i].aoe_learnt_deg));
  }
  EXPECT_EQ(a.gate_reason, b.gate_reason);
  // And the text itself is stable: written again, the same bytes.
  EXPECT_EQ(ParamSetToJson(*back), json);
  EXPECT_EQ(Json::parse(json)["dynamic_gyro"]["model"], kDynamicGyroModelText);
}

TEST(DynamicGyroJsonTest, AbsentBlockStaysAbsentAndTheDocumentKeepsItsBytes) {
  const core::ParamSet p = StaticParams();
  const std::string json = ParamSetToJson(p);
  EXPECT_EQ(json.find("dynamic_gyro"), std::string::npos);
  absl::StatusOr<core::ParamSet> back = ParamSetFromJson(json);
  ASSERT_TRUE(back.ok()) << back.status();
  EXPECT_FALSE(back->dynamic_gyro.has_value());
  EXPECT_EQ(ParamSetToJson(*back), json);
  // The static model's text is not touched by the block's existence.
  EXPECT_EQ(Json::parse(json)["model"], core::kModelText);
}

TEST(DynamicGyroJsonTest, NoFilterIsABlockToo) {
  std::mt19937_64 rng(kSeed);
  core::ParamSet p = StaticParams();
  p.dynamic_gyro = RandomBlock(rng, 0, 1);
  absl::StatusOr<core::ParamSet> back = ParamSetFromJson(ParamSetToJson(p));
  ASSERT_TRUE(back.ok()) << back.status();
  EXPECT_EQ(back->dynamic_gyro->taps, 0);
  EXPECT_TRUE(back->dynamic_gyro->weights.empty());
}

struct Refusal {
  const char* what;
  void (*edit)(Json&);
  const char* message;  // the start of the error: path and reason
};

const Refusal kRefusals[] = {
    {"weights short",
     [](Json& b) {
       b["taps"] = 1;
       b["dilation"] = 1;
       b["weights"].erase(0);
     },
     "dynamic_gyro.weights: 35 values but taps*18 = 18 expected"},
    {"weights count", [](Json& b) { b["weights"].erase(0); },
     "dynamic_gyro.weights: 35 values but taps*18 = 36 expected"},
    {"weight null", [](Json& b) { b["weights"][5] = nullptr; },
     "dynamic_gyro.weights[5]: expected a number"},
    {"weight string", [](Json& b) { b["weights"][0] = "1"; },
     "dynamic_gyro.weights[0]: expected a number"},
    {"weights not array", [](Json& b) { b["weights"] = 1.0; },
     "dynamic_gyro.weights: expected an array"},
    {"taps negative", [](Json& b) { b["taps"] = -1; }, "dynamic_gyro.taps: negative"},
    {"taps fraction", [](Json& b) { b["taps"] = 1.5; }, "dynamic_gyro.taps: expected an integer"},
    {"dilation zero", [](Json& b) { b["dilation"] = 0; },
     "dynamic_gyro.dilation: must be 1 or more"},
    {"window huge", [](Json& b) { b["dilation"] = 1000000; },
     "dynamic_gyro.dilation: window (taps-1)*dilation+1 = 1000001 samples"},
    {"rate zero", [](Json& b) { b["rate_hz"] = 0; }, "dynamic_gyro.rate_hz: must be a finite"},
    {"rate negative", [](Json& b) { b["rate_hz"] = -200; },
     "dynamic_gyro.rate_hz: must be a finite"},
    {"rate missing", [](Json& b) { b.erase("rate_hz"); }, "dynamic_gyro.rate_hz: missing"},
    {"rate null", [](Json& b) { b["rate_hz"] = nullptr; },
     "dynamic_gyro.rate_hz: expected a number"},
    {"weights missing", [](Json& b) { b.erase("weights"); }, "dynamic_gyro.weights: missing"},
    {"taps missing", [](Json& b) { b.erase("taps"); }, "dynamic_gyro.taps: missing"},
    {"delay null", [](Json& b) { b["delay_s"] = nullptr; },
     "dynamic_gyro.delay_s: expected a number"},
    {"odd rate size", [](Json& b) { b["odd_rate_per_rad_s"].erase(0); },
     "dynamic_gyro.odd_rate_per_rad_s: expected an array of 3"},
    {"envelope negative", [](Json& b) { b["envelope"]["max_abs_rate_rad_s"][1] = -1.0; },
     "dynamic_gyro.envelope.max_abs_rate_rad_s[1]: negative"},
    {"envelope missing", [](Json& b) { b.erase("envelope"); }, "dynamic_gyro.envelope: missing"},
    {"envelope missing member", [](Json& b) { b["envelope"].erase("max_abs_accel_m_s2"); },
     "dynamic_gyro.envelope.max_abs_accel_m_s2: missing"},
    {"ridge negative", [](Json& b) { b["ridge_lambda"] = -1; },
     "dynamic_gyro.ridge_lambda: must be a finite number >= 0"},
    {"training not array", [](Json& b) { b["training"] = "room1"; },
     "dynamic_gyro.training: expected an array"},
    {"training name", [](Json& b) { b["training"][1].erase("name"); },
     "dynamic_gyro.training[1].name: missing"},
    {"training aoe", [](Json& b) { b["training"][0]["aoe_learnt_deg"] = "low"; },
     "dynamic_gyro.training[0].aoe_learnt_deg: expected a number or null"},
    {"block not object", [](Json& b) { b = Json::array(); }, "dynamic_gyro: expected an object"},
};

TEST(DynamicGyroJsonTest, MalformedBlocksAreRefusedWithTheirPath) {
  for (const Refusal& r : kRefusals) {
    absl::StatusOr<core::ParamSet> p = ParamSetFromJson(WithEditedBlock(r.edit));
    ASSERT_FALSE(p.ok()) << r.what;
    EXPECT_EQ(p.status().code(), absl::StatusCode::kInvalidArgument) << r.what;
    EXPECT_EQ(std::string(p.status().message()).rfind(r.message, 0), 0u)
        << r.what << ": " << p.status().message();
  }
}

// JSON cannot spell NaN or infinity, but a block built in code can: the shared check refuses.
TEST(DynamicGyroJsonTest, NonFiniteValuesInABlockAreRefused) {
  std::mt19937_64 rng(kSeed);
  const core::DynamicGyro good = RandomBlock(rng, 2, 3);
  ASSERT_TRUE(DynamicGyroIsValid(good, "dynamic_gyro").ok());
  core::DynamicGyro b = good;
  b.weights[7] = std::numeric_limits<double>::infinity();
  EXPECT_EQ(DynamicGyroIsValid(b, "dynamic_gyro").message(), "dynamic_gyro.weights[7]: not finite");
  b = good;
  b.delay_s = kNan;
  EXPECT_EQ(DynamicGyroIsValid(b, "dynamic_gyro").message(), "dynamic_gyro.delay_s: not finite");
  b = good;
  b.odd_rate(2) = kNan;
  EXPECT_EQ(DynamicGyroIsValid(b, "dynamic_gyro").message(),
            "dynamic_gyro.odd_rate_per_rad_s[2]: not finite");
  b = good;
  b.rate_hz = std::numeric_limits<double>::infinity();
  EXPECT_EQ(DynamicGyroIsValid(b, "dynamic_gyro").message(),
            "dynamic_gyro.rate_hz: must be a finite number > 0");
  b = good;
  b.envelope.max_abs_accel_m_s2(0) = kNan;
  EXPECT_EQ(DynamicGyroIsValid(b, "dynamic_gyro").message(),
            "dynamic_gyro.envelope.max_abs_accel_m_s2[0]: not finite");
}

TEST(DynamicGyroJsonTest, ABlockNeedsAGyroscope) {
  std::mt19937_64 rng(kSeed);
  core::ParamSet p = StaticParams();
  p.dynamic_gyro = RandomBlock(rng, 1, 1);
  Json j = Json::parse(ParamSetToJson(p));
  j.erase("gyro");
  absl::StatusOr<core::ParamSet> back = ParamSetFromJson(j.dump());
  ASSERT_FALSE(back.ok());
  EXPECT_EQ(std::string(back.status().message()).rfind("dynamic_gyro: a dynamic gyro block", 0), 0u)
      << back.status();
}

TEST(DynamicGyroJsonTest, InsideAReportThePathSaysParameters) {
  Json report = Json::object();
  report["format"] = "imucal-report v1";
  report["parameters"] = Json::parse(WithEditedBlock([](Json& b) { b["dilation"] = 0; }));
  absl::StatusOr<core::ParamSet> p = ParamSetFromJson(report.dump());
  ASSERT_FALSE(p.ok());
  EXPECT_EQ(std::string(p.status().message()).rfind("parameters.dynamic_gyro.dilation:", 0), 0u)
      << p.status();
}

}  // namespace
}  // namespace imucal::formats
