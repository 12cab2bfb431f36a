// Issue 27 on real data: TUM-VI rooms 2/4/6 with a block learnt on rooms 1/3/5 only (never the
// other way), through the same core calls `imucal learn` makes. The figures it asserts are
// measured ones, with a margin (docs/motion.md has the table and the command).
#include <cstdio>
#include <string>
#include <vector>

#include "core/motion/learn.h"
#include "gtest/gtest.h"
#include "importers/reference.h"

namespace imucal::core::motion {
namespace {

const std::string kRoomDir = IMUCAL_SHARED_DIR "/data/real/tumvi-room";

MotionRecording Room(int n) {
  const std::string base = kRoomDir + "/room" + std::to_string(n);
  absl::StatusOr<MotionRecording> r =
      importers::ReadMotionRecording(base + ".csv:" + base + "_gt.csv");
  EXPECT_TRUE(r.ok()) << r.status();
  return r.ok() ? *r : MotionRecording();
}

TEST(LearnTumVi, Rooms246FromRooms135) {
  LearnOptions options;
  options.fit.threads = 2;
  std::vector<MotionRecording> rooms;
  for (int n = 1; n <= 6; ++n) rooms.push_back(Room(n));
  std::vector<PreparedRecording> prepared;
  for (const MotionRecording& r : rooms) {
    absl::StatusOr<PreparedRecording> p = Prepare(r, options);
    ASSERT_TRUE(p.ok()) << p.status();
    std::printf("%s: %s\n", r.name.c_str(), p->alignment.summary.c_str());
    prepared.push_back(*p);
  }
  const std::vector<const PreparedRecording*> train = {&prepared[0], &prepared[2], &prepared[4]};
  absl::StatusOr<LearnResult> result = Learn(train, std::nullopt, options);
  ASSERT_TRUE(result.ok()) << result.status();
  std::printf("gate: %s\n", result->gate_reason.c_str());
  for (const std::string& note : result->notes) std::printf("note: %s\n", note.c_str());
  const DynamicGyro& b = *result->candidate.params.dynamic_gyro;
  std::printf("delay %.3f +- %.3f ms, odd %g %g %g (+- %g %g %g), taps %d\n", 1e3 * b.delay_s,
              1e3 * b.delay_std_error_s, b.odd_rate(0), b.odd_rate(1), b.odd_rate(2),
              b.odd_rate_std_error(0), b.odd_rate_std_error(1), b.odd_rate_std_error(2), b.taps);
  // Measured (docs/motion.md): raw 2.69 / 1.65 / 0.95, static (C, b, G in motion on 1/3/5)
  // 1.29 / 1.01 / 1.33, the gate refuses the block (room 5 held out gets worse), so learnt ==
  // static. The aim (mean <= 0.7, each <= 0.9) is NOT reached; these bounds are the
  // measured figures with a 15 % margin, so a regression fails.
  const double kMaxStatic[] = {1.5, 1.2, 1.55};
  const double kMaxRaw[] = {3.1, 1.9, 1.1};
  double mean_learnt = 0.0;
  int index = 0;
  for (int room : {2, 4, 6}) {
    const Evaluation e = Evaluate(prepared[room - 1], *result, options);
    std::printf(
        "room%d AOE raw %.2f rest %.2f static %.2f learnt %.2f | heading %.2f %.2f %.2f "
        "%.2f (%s)\n",
        room, e.raw.aoe_deg, e.rest_bias.aoe_deg, e.static_model.aoe_deg, e.learnt.aoe_deg,
        e.raw.final_heading_deg, e.rest_bias.final_heading_deg, e.static_model.final_heading_deg,
        e.learnt.final_heading_deg, e.rest_note.c_str());
    mean_learnt += e.learnt.aoe_deg / 3.0;
    EXPECT_LT(e.raw.aoe_deg, kMaxRaw[index]) << "room" << room;
    EXPECT_LT(e.static_model.aoe_deg, kMaxStatic[index]) << "room" << room;
    EXPECT_LE(e.learnt.aoe_deg, e.static_model.aoe_deg + 1e-9) << "room" << room;
    ++index;
  }
  std::printf("mean learnt %.3f\n", mean_learnt);
  EXPECT_LT(mean_learnt, 1.4);
}

}  // namespace
}  // namespace imucal::core::motion
