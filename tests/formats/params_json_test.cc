#include "formats/params_json.h"

#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <random>
#include <string>

#include "Eigen/Core"
#include "absl/strings/match.h"
#include "core/params.h"
#include "gtest/gtest.h"
#include "nlohmann/json.hpp"

namespace imucal::formats {
namespace {

// Ordered, so that evidence objects keep their key order through the test's edits.
using Json = nlohmann::ordered_json;
constexpr double kNan = std::numeric_limits<double>::quiet_NaN();

// Bitwise, so NaN == NaN and -0.0 != 0.0: the round trip must be exact.
bool SameBits(double a, double b) { return std::memcmp(&a, &b, sizeof(double)) == 0; }

template <typename Derived>
void ExpectSameBits(const Eigen::MatrixBase<Derived>& a, const Eigen::MatrixBase<Derived>& b,
                    const std::string& what) {
  for (Eigen::Index i = 0; i < a.size(); ++i) {
    EXPECT_TRUE(SameBits(a(i), b(i))) << what << " element " << i << ": " << a(i) << " vs " << b(i);
  }
}

void ExpectSameAccel(const core::AccelParams& a, const core::AccelParams& b,
                     const std::string& what) {
  ExpectSameBits(a.bias, b.bias, what + ".bias");
  ExpectSameBits(a.scale, b.scale, what + ".scale");
  ExpectSameBits(a.tri_angles, b.tri_angles, what + ".tri_angles");
  ExpectSameBits(a.frame_angles, b.frame_angles, what + ".frame_angles");
  ExpectSameBits(a.quadratic, b.quadratic, what + ".quadratic");
}

void ExpectSameParamSet(const core::ParamSet& a, const core::ParamSet& b) {
  EXPECT_EQ(a.device, b.device);
  EXPECT_EQ(a.version, b.version);
  EXPECT_EQ(a.created_at, b.created_at);
  EXPECT_EQ(a.accel_unit, b.accel_unit);
  EXPECT_EQ(a.gyro_unit, b.gyro_unit);
  EXPECT_TRUE(SameBits(a.gravity_m_s2, b.gravity_m_s2));
  ExpectSameAccel(a.accel, b.accel, "accel");
  ExpectSameBits(a.gyro.matrix, b.gyro.matrix, "gyro.matrix");
  ExpectSameBits(a.gyro.bias, b.gyro.bias, "gyro.bias");
  ExpectSameBits(a.gyro.accel_coupling, b.gyro.accel_coupling, "gyro.accel_coupling");
  EXPECT_EQ(a.gyro_calibrated, b.gyro_calibrated);
  ExpectSameAccel(a.stderrs.accel, b.stderrs.accel, "stderr.accel");
  ExpectSameBits(a.stderrs.gyro_matrix, b.stderrs.gyro_matrix, "stderr.gyro_matrix");
  ExpectSameBits(a.stderrs.gyro_bias, b.stderrs.gyro_bias, "stderr.gyro_bias");
  EXPECT_TRUE(SameBits(a.quality_accel_rms_m_s2, b.quality_accel_rms_m_s2));
  EXPECT_TRUE(SameBits(a.quality_gyro_static_rms_rad_s, b.quality_gyro_static_rms_rad_s));
  EXPECT_EQ(a.source_session, b.source_session);
  EXPECT_EQ(a.software, b.software);
  EXPECT_TRUE(SameBits(a.effect_reference.temperature_c, b.effect_reference.temperature_c));
  EXPECT_TRUE(SameBits(a.effect_reference.time_s, b.effect_reference.time_s));
  ASSERT_EQ(a.effects.size(), b.effects.size());
  for (size_t i = 0; i < a.effects.size(); ++i) {
    const core::Effect& x = a.effects[i];
    const core::Effect& y = b.effects[i];
    EXPECT_EQ(x.sensor, y.sensor) << i;
    EXPECT_EQ(x.axis, y.axis) << i;
    EXPECT_EQ(x.regressor, y.regressor) << i;
    EXPECT_TRUE(SameBits(x.coefficient, y.coefficient)) << i;
    EXPECT_TRUE(SameBits(x.std_error, y.std_error)) << i;
    EXPECT_TRUE(SameBits(x.error_before, y.error_before)) << i;
    EXPECT_TRUE(SameBits(x.error_after, y.error_after)) << i;
    EXPECT_EQ(x.applied, y.applied) << i;
    EXPECT_EQ(x.evidence, y.evidence) << i;
  }
}

Eigen::Vector3d RandomVec(std::mt19937_64& rng) {
  // Values whose shortest decimal form is long (full 17 digits), and a negative zero.
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  return Eigen::Vector3d(u(rng) * 1e-3, u(rng), u(rng) * 1e5);
}

core::ParamSet FullParamSet(uint64_t seed) {
  std::mt19937_64 rng(seed);
  core::ParamSet p;
  p.device = "robot-0042 \"lab\" \\ unit";
  p.version = 7;
  p.created_at = "2026-11-21T10:00:00Z";
  p.accel_unit = core::AccelUnit::kCounts;
  p.gyro_unit = core::GyroUnit::kDegPerSecond;
  p.gravity_m_s2 = 9.80412345678901;
  p.accel.bias = RandomVec(rng);
  p.accel.scale = RandomVec(rng);
  p.accel.tri_angles = RandomVec(rng);
  p.accel.frame_angles = Eigen::Vector3d(-0.0, 1e-300, -2.5e-17);
  p.accel.quadratic = RandomVec(rng);
  p.gyro.matrix.row(0) = RandomVec(rng).transpose();
  p.gyro.matrix.row(1) = RandomVec(rng).transpose();
  p.gyro.matrix.row(2) = RandomVec(rng).transpose();
  p.gyro.bias = RandomVec(rng);
  p.gyro.accel_coupling << 1, 2, 3, 4, 5, 6, 7, 8, 9.000000000000002;
  p.gyro_calibrated = true;
  p.stderrs.accel.bias = RandomVec(rng);
  p.stderrs.accel.scale = Eigen::Vector3d(1e-5, kNan, 3e-5);
  p.stderrs.accel.tri_angles = Eigen::Vector3d::Constant(kNan);
  p.stderrs.accel.frame_angles = Eigen::Vector3d(kNan, 0.0, 1e-4);
  p.stderrs.accel.quadratic = RandomVec(rng);
  p.stderrs.gyro_matrix = Eigen::Matrix3d::Constant(1e-4);
  p.stderrs.gyro_matrix(1, 2) = kNan;
  p.stderrs.gyro_bias = Eigen::Vector3d(kNan, 2e-6, 3e-6);
  core::Effect e;
  e.sensor = core::Sensor::kGyro;
  e.axis = 1;
  e.regressor = "ax";
  e.coefficient = 1.2e-4;
  e.std_error = 1.1e-5;
  e.error_before = 8.1e-4;
  e.error_after = 1.9e-4;
  e.evidence = "held-out RMS 8.1e-4 -> 1.9e-4, BIC -12.3";
  p.effects.push_back(e);
  e.sensor = core::Sensor::kAccel;
  e.axis = 2;
  e.regressor = "temperature^2";
  e.std_error = kNan;
  e.applied = false;
  e.evidence = R"({"what":"held-out RMS","bic":-3.5})";
  p.effects.push_back(e);
  e.axis = 0;
  e.regressor = "ax*temperature";  // not canonical: kept as written
  e.evidence = "";
  e.applied = true;
  p.effects.push_back(e);
  // A centred quadratic about the stated reference (report.md, effect_reference).
  p.effect_reference.temperature_c = 31.2;
  p.effect_reference.time_s = 118;
  e.sensor = core::Sensor::kGyro;
  e.regressor = "(temperature-31.2)^2";
  p.effects.push_back(e);
  e.regressor = "(time-118)";
  e.applied = false;
  p.effects.push_back(e);
  // A rate term found on the moves (core/move_effects.h): the magnitude form `|gz|`, no static
  // figures (null), the moves' in the evidence.
  e.axis = 2;
  e.regressor = "gz*|gz|";
  e.applied = true;
  e.error_before = e.error_after = kNan;
  e.evidence = R"({"what":"rotations between poses","moves_heldout_before_rad":0.0019})";
  p.effects.push_back(e);
  p.quality_accel_rms_m_s2 = 0.0004;
  p.quality_gyro_static_rms_rad_s = 2e-5;
  p.source_session = "session-17";
  p.software = "imucal 0.1.0";
  return p;
}

core::ParamSet ParseOk(const std::string& json) {
  const absl::StatusOr<core::ParamSet> p = ParamSetFromJson(json);
  EXPECT_TRUE(p.ok()) << p.status();
  return p.ok() ? *p : core::ParamSet();
}

TEST(ParamsJsonTest, RoundTripIsExact) {
  for (uint64_t seed : {1u, 2u, 3u}) {
    SCOPED_TRACE(testing::Message() << "seed " << seed);
    const core::ParamSet p = FullParamSet(seed);
    const std::string json = ParamSetToJson(p);
    const core::ParamSet back = ParseOk(json);
    ExpectSameParamSet(p, back);
    EXPECT_EQ(ParamSetToJson(back), json);
  }
  // The defaults too.
  ExpectSameParamSet(core::ParamSet(), ParseOk(ParamSetToJson(core::ParamSet())));
}

TEST(ParamsJsonTest, WritesTheSpecLayout) {
  const core::ParamSet p = FullParamSet(1);
  const std::string text = ParamSetToJson(p);
  EXPECT_TRUE(absl::StartsWith(text, "{\n  \"format\": \"imucal-params v1\",\n")) << text;
  const Json j = Json::parse(text);
  EXPECT_EQ(j["model"], core::kModelText);
  EXPECT_EQ(j["version"], 7);
  EXPECT_EQ(j["gravity"], p.gravity_m_s2);
  EXPECT_EQ(j["accel"]["input_unit"], "counts");
  EXPECT_EQ(j["gyro"]["input_unit"], "deg/s");
  EXPECT_EQ(j["gyro"]["calibrated"], true);
  // NaN standard errors are null.
  EXPECT_TRUE(j["accel"]["stderr"]["scale"][1].is_null());
  EXPECT_EQ(j["accel"]["stderr"]["scale"][0], 1e-5);
  EXPECT_TRUE(j["gyro"]["stderr"]["matrix"][1][2].is_null());
  EXPECT_TRUE(j["effects"][1]["stderr"].is_null());
  // Matrices row-major: matrix[r][c].
  EXPECT_EQ(j["gyro"]["matrix"][1][2], p.gyro.matrix(1, 2));
  EXPECT_EQ(j["gyro"]["accel_coupling"][2][0], 7.0);
  EXPECT_EQ(j["gyro"]["scale"][2], p.gyro.matrix(2, 2));
  const Eigen::Matrix3d m = p.accel.Misalignment();
  EXPECT_EQ(j["accel"]["misalignment"][2][1], m(2, 1));
  // Effects as in report.md.
  EXPECT_EQ(j["effects"][0]["sensor"], "gyro");
  EXPECT_EQ(j["effects"][0]["axis"], "y");
  EXPECT_EQ(j["effects"][0]["regressor"], "ax");
  EXPECT_EQ(j["effects"][0]["evidence"]["what"], p.effects[0].evidence);
  EXPECT_EQ(j["effects"][1]["evidence"]["bic"], -3.5);
  EXPECT_EQ(j["effects"][1]["applied"], false);
  EXPECT_EQ(j["quality"]["accel_rms"], 0.0004);
  EXPECT_EQ(j["source"]["software"], "imucal 0.1.0");
  EXPECT_EQ(j["effect_reference"]["temperature"], 31.2);
  EXPECT_EQ(j["effect_reference"]["time"], 118);
  EXPECT_EQ(j["effects"][3]["regressor"], "(temperature-31.2)^2");
  // A parameter set without centred effects writes no reference (the layout older readers saw).
  EXPECT_FALSE(Json::parse(ParamSetToJson(core::ParamSet())).contains("effect_reference"));
}

// Parameter sets from before centred factors have no effect_reference: it reads as 0, the
// meaning their plain names had. A centred name the stated reference contradicts is refused
// with the effect's path.
TEST(ParamsJsonTest, EffectReferenceOptionalAndCheckedAgainstTheNames) {
  Json j = Json::parse(ParamSetToJson(FullParamSet(1)));
  Json old = j;
  old.erase("effect_reference");
  old["effects"].erase(4);
  old["effects"].erase(3);
  const core::ParamSet back = ParseOk(old.dump());
  EXPECT_EQ(back.effect_reference, core::EffectReference());
  Json wrong = j;
  wrong["effect_reference"]["temperature"] = 30.0;
  absl::StatusOr<core::ParamSet> bad = ParamSetFromJson(wrong.dump());
  ASSERT_FALSE(bad.ok());
  EXPECT_EQ(bad.status().message(),
            "effects[3].regressor: written (temperature-31.2) but effect_reference.temperature "
            "makes it (temperature-30)");
  Json missing = j;
  missing.erase("effect_reference");
  bad = ParamSetFromJson(missing.dump());
  ASSERT_FALSE(bad.ok());
  EXPECT_TRUE(absl::StartsWith(bad.status().message(), "effects[3].regressor: written "))
      << bad.status();
  Json not_number = j;
  not_number["effect_reference"]["time"] = "soon";
  bad = ParamSetFromJson(not_number.dump());
  ASSERT_FALSE(bad.ok());
  EXPECT_TRUE(absl::StartsWith(bad.status().message(), "effect_reference.time")) << bad.status();
}

TEST(ParamsJsonTest, AcceptsAWholeReport) {
  const core::ParamSet p = FullParamSet(2);
  Json report = {{"format", "imucal-report v1"},
                 {"device", "robot-0042"},
                 {"verdict", "pass"},
                 {"poses", Json::array()},
                 {"parameters", Json::parse(ParamSetToJson(p))}};
  ExpectSameParamSet(p, ParseOk(report.dump()));

  report["parameters"]["accel"]["scale"][0] = "1.0";
  const absl::StatusOr<core::ParamSet> bad = ParamSetFromJson(report.dump());
  ASSERT_FALSE(bad.ok());
  EXPECT_EQ(bad.status().message(), "parameters.accel.scale[0]: expected a number");

  report.erase("parameters");
  const absl::StatusOr<core::ParamSet> missing = ParamSetFromJson(report.dump());
  ASSERT_FALSE(missing.ok());
  EXPECT_TRUE(absl::StartsWith(missing.status().message(), "parameters: missing"));

  report["parameters"] = {{"format", "imucal-report v1"}};
  const absl::StatusOr<core::ParamSet> nested = ParamSetFromJson(report.dump());
  ASSERT_FALSE(nested.ok());
  EXPECT_TRUE(absl::StartsWith(nested.status().message(),
                               "parameters.format: expected \"imucal-params v1\""))
      << nested.status();
}

TEST(ParamsJsonTest, MinimalDocumentTakesDefaults) {
  const std::string json = R"({
    "format": "imucal-params v1",
    "accel": {"bias": [0, 0, 0], "scale": [1, 1, 1], "tri_angles": [0, 0, 0],
              "frame_angles": [0, 0, 0], "quadratic": [0, 0, 0], "input_unit": "g"},
    "gyro": {"bias": [0.1, 0.2, 0.3], "matrix": [[1, 0, 0], [0, 1, 0], [0, 0, 1]],
             "input_unit": "rad/s"},
    "some_future_field": {"ignored": true}
  })";
  const core::ParamSet p = ParseOk(json);
  EXPECT_EQ(p.device, "");
  EXPECT_EQ(p.version, 0);
  EXPECT_EQ(p.accel_unit, core::AccelUnit::kG);
  EXPECT_EQ(p.gravity_m_s2, core::kStandardGravity);
  EXPECT_EQ(p.gyro.bias, Eigen::Vector3d(0.1, 0.2, 0.3));
  EXPECT_TRUE(p.gyro.accel_coupling.isZero(0.0));
  EXPECT_FALSE(p.gyro_calibrated);
  EXPECT_TRUE(p.effects.empty());
  // Standard errors not stated are unknown, not zero.
  EXPECT_TRUE(p.stderrs.accel.scale.array().isNaN().all());
  EXPECT_TRUE(p.stderrs.gyro_matrix.array().isNaN().all());
}

TEST(ParamsJsonTest, EvidenceFormsAreAccepted) {
  Json j = Json::parse(ParamSetToJson(FullParamSet(1)));
  j["effects"][0]["evidence"] = "plain text";
  j["effects"][1]["evidence"] = {{"what", "only what"}};
  j["effects"][2]["evidence"] = {{"what", "x"}, {"held_out_rms", 0.25}};
  const core::ParamSet p = ParseOk(j.dump());
  EXPECT_EQ(p.effects[0].evidence, "plain text");
  EXPECT_EQ(p.effects[1].evidence, "only what");
  EXPECT_EQ(Json::parse(p.effects[2].evidence), j["effects"][2]["evidence"]);
  j["effects"][2]["evidence"] = 3;
  const absl::StatusOr<core::ParamSet> bad = ParamSetFromJson(j.dump());
  ASSERT_FALSE(bad.ok());
  EXPECT_TRUE(absl::StartsWith(bad.status().message(), "effects[2].evidence: expected"));
}

struct ErrorCase {
  const char* name;
  void (*mutate)(Json& j);
  const char* message_prefix;
};

TEST(ParamsJsonTest, ErrorsNameTheJsonPath) {
  const ErrorCase cases[] = {
      {"scale type", [](Json& j) { j["accel"]["scale"][2] = "x"; },
       "accel.scale[2]: expected a number"},
      {"null value", [](Json& j) { j["accel"]["bias"][0] = nullptr; },
       "accel.bias[0]: expected a number"},
      {"short vector",
       [](Json& j) {
         j["accel"]["quadratic"] = {1, 2};
       },
       "accel.quadratic: expected an array of 3 numbers"},
      {"format", [](Json& j) { j["format"] = "imucal-params v2"; },
       "format: expected \"imucal-params v1\""},
      {"no format", [](Json& j) { j.erase("format"); }, "format: missing"},
      {"regressor", [](Json& j) { j["effects"][1]["regressor"] = "ax*bz"; },
       "effects[1].regressor: unknown regressor \"ax*bz\""},
      {"regressor power", [](Json& j) { j["effects"][0]["regressor"] = "ax^3"; },
       "effects[0].regressor: unknown regressor"},
      {"axis", [](Json& j) { j["effects"][0]["axis"] = "w"; },
       "effects[0].axis: expected \"x\", \"y\" or \"z\""},
      {"sensor", [](Json& j) { j["effects"][2]["sensor"] = "mag"; },
       "effects[2].sensor: expected \"accel\" or \"gyro\""},
      {"coefficient", [](Json& j) { j["effects"][0].erase("coefficient"); },
       "effects[0].coefficient: missing"},
      {"effects type", [](Json& j) { j["effects"] = Json::object(); },
       "effects: expected an array"},
      {"matrix row",
       [](Json& j) {
         j["gyro"]["matrix"][1] = {1, 2};
       },
       "gyro.matrix[1]: expected an array of 3 numbers"},
      {"matrix element", [](Json& j) { j["gyro"]["matrix"][2][0] = true; },
       "gyro.matrix[2][0]: expected a number"},
      {"no matrix", [](Json& j) { j["gyro"].erase("matrix"); }, "gyro.matrix: missing"},
      {"coupling", [](Json& j) { j["gyro"]["accel_coupling"] = 0; },
       "gyro.accel_coupling: expected 3 rows"},
      {"stderr type", [](Json& j) { j["gyro"]["stderr"]["bias"][1] = "n/a"; },
       "gyro.stderr.bias[1]: expected a number or null"},
      {"accel unit", [](Json& j) { j["accel"]["input_unit"] = "furlongs"; },
       "accel.input_unit: unknown accel unit \"furlongs\""},
      {"gyro unit", [](Json& j) { j["gyro"]["input_unit"] = 1; },
       "gyro.input_unit: expected a string"},
      {"version", [](Json& j) { j["version"] = 1.5; }, "version: expected an integer"},
      {"calibrated", [](Json& j) { j["gyro"]["calibrated"] = "yes"; },
       "gyro.calibrated: expected true or false"},
      {"accel type", [](Json& j) { j["accel"] = Json::array(); }, "accel: expected an object"},
      {"quality", [](Json& j) { j["quality"]["accel_rms"] = "small"; },
       "quality.accel_rms: expected a number or null"},
      {"source", [](Json& j) { j["source"]["session"] = 17; }, "source.session: expected a string"},
  };
  const Json valid = Json::parse(ParamSetToJson(FullParamSet(3)));
  for (const ErrorCase& c : cases) {
    Json j = valid;
    c.mutate(j);
    const absl::StatusOr<core::ParamSet> p = ParamSetFromJson(j.dump());
    ASSERT_FALSE(p.ok()) << c.name;
    EXPECT_EQ(p.status().code(), absl::StatusCode::kInvalidArgument) << c.name;
    EXPECT_TRUE(absl::StartsWith(p.status().message(), c.message_prefix))
        << c.name << ": got " << p.status();
  }
}

TEST(ParamsJsonTest, RejectsNonJsonAndNonObjects) {
  for (const char* text : {"", "{", "{\"format\": NaN}", "not json"}) {
    const absl::StatusOr<core::ParamSet> p = ParamSetFromJson(text);
    ASSERT_FALSE(p.ok()) << text;
    EXPECT_TRUE(absl::StartsWith(p.status().message(), "invalid JSON")) << p.status();
  }
  const absl::StatusOr<core::ParamSet> array = ParamSetFromJson("[1, 2]");
  ASSERT_FALSE(array.ok());
  EXPECT_EQ(array.status().message(), "(top level): expected an object");
}

TEST(ParamsJsonTest, UnitNamesMatchTheCaptureHeader) {
  // The SDK keeps its own copy of the names (it must not link core's capture.cc); this test
  // binary links core, so check that the two agree.
  for (core::AccelUnit u :
       {core::AccelUnit::kMetersPerSecond2, core::AccelUnit::kG, core::AccelUnit::kCounts}) {
    EXPECT_EQ(UnitName(u), core::AccelUnitName(u));
  }
  for (core::GyroUnit u :
       {core::GyroUnit::kRadPerSecond, core::GyroUnit::kDegPerSecond, core::GyroUnit::kCounts}) {
    EXPECT_EQ(UnitName(u), core::GyroUnitName(u));
  }
  EXPECT_EQ(UnitName(core::AccelUnit::kMetersPerSecond2), "m/s^2");
  EXPECT_EQ(UnitName(core::GyroUnit::kDegPerSecond), "deg/s");
}

}  // namespace
}  // namespace imucal::formats

// A parameter set fitted without a gyroscope: no gyro key anywhere, read back as such.
namespace imucal::formats {
namespace {

bool HasGyroKey(const nlohmann::ordered_json& j) {
  if (j.is_object()) {
    for (const auto& [key, value] : j.items()) {
      if (key.find("gyro") != std::string::npos || HasGyroKey(value)) return true;
    }
  } else if (j.is_array()) {
    for (const auto& value : j) {
      if (HasGyroKey(value)) return true;
    }
  }
  return false;
}

TEST(ParamsJsonAccelOnlyTest, WritesNoGyroKeyAndReadsBackWithoutGyro) {
  core::ParamSet params;
  params.has_gyro = false;
  params.accel.bias = Eigen::Vector3d(0.1, 0.2, 0.3);
  core::NoiseFigures noise;
  noise.rate_hz = 100;
  noise.accel.noise_density = Eigen::Vector3d(1e-3, 1e-3, 1e-3);
  params.noise = noise;
  const std::string text = ParamSetToJson(params);
  const auto j = nlohmann::ordered_json::parse(text);
  EXPECT_FALSE(HasGyroKey(j)) << text;
  EXPECT_EQ(j["model"], core::kAccelOnlyModelText);
  absl::StatusOr<core::ParamSet> back = ParamSetFromJson(text);
  ASSERT_TRUE(back.ok()) << back.status();
  EXPECT_FALSE(back->has_gyro);
  EXPECT_EQ(back->accel.bias, params.accel.bias);
  ASSERT_TRUE(back->noise.has_value());
  EXPECT_EQ(ParamSetToJson(*back), text);
}

TEST(ParamsJsonAccelOnlyTest, GyroEffectWithoutGyroIsRefused) {
  core::ParamSet params;
  params.has_gyro = false;
  core::Effect e;
  e.sensor = core::Sensor::kGyro;
  e.regressor = "temperature";
  params.effects = {e};
  absl::StatusOr<core::ParamSet> back = ParamSetFromJson(ParamSetToJson(params));
  ASSERT_FALSE(back.ok());
  EXPECT_TRUE(absl::StrContains(back.status().message(), "effects[0].sensor"));
}

TEST(ParamsJsonAccelOnlyTest, ANoiseBlockWithoutGyroNeedsAParamSetWithoutGyro) {
  core::ParamSet params;
  params.noise = core::NoiseFigures();
  auto j = nlohmann::ordered_json::parse(ParamSetToJson(params));
  j["noise"].erase("gyro");
  absl::StatusOr<core::ParamSet> back = ParamSetFromJson(j.dump());
  ASSERT_FALSE(back.ok());
  EXPECT_TRUE(absl::StrContains(back.status().message(), "noise.gyro: missing"));
}

}  // namespace
}  // namespace imucal::formats
