// Store: poses and pair verdicts (storage/store_poses.cc).
#include <vector>

#include "gtest/gtest.h"
#include "storage/store.h"
#include "tests/storage/store_test_util.h"

namespace imucal::storage {
namespace {

TEST_P(BatchTest, PosesAreReplacedAsAWhole) {
  std::vector<Pose> poses(3);
  for (int i = 0; i < 3; ++i) {
    poses[i].index = i;
    poses[i].t_start_s = 10.0 * i;
    poses[i].t_end_s = 10.0 * i + 5;
    poses[i].detail_json = R"({"samples": 1000})";
  }
  poses[2].used = false;
  poses[2].reason = "moved during capture";
  ASSERT_OK(store_->PutPoses("S1", poses, "server"));
  poses.pop_back();
  ASSERT_OK(store_->PutPoses("S1", poses, "server"));
  ASSERT_OK_AND_ASSIGN(std::vector<Pose> got, store_->ListPoses("S1"));
  ASSERT_EQ(got.size(), 2u);
  EXPECT_EQ(got[1].index, 1);
  EXPECT_EQ(got[1].t_start_s, 10.0);
  EXPECT_EQ(got[1].t_end_s, 15.0);
  EXPECT_TRUE(got[1].used);
  EXPECT_EQ(got[1].detail_json, R"({"samples": 1000})");
  EXPECT_EQ(got[1].session_id, "S1");

  std::vector<Pose> misnumbered = poses;
  misnumbered[1].index = 5;
  EXPECT_EQ(store_->PutPoses("S1", misnumbered, "server").code(),
            absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(store_->PutPoses("S404", poses, "server").code(), absl::StatusCode::kNotFound);
  EXPECT_EQ(store_->ListPoses("S1").value().size(), 2u);
}

TEST_P(BatchTest, SavePosesUpsertsPosesAndPairs) {
  Pose a, b;
  a.index = 0, a.t_start_s = 1, a.t_end_s = 2, a.face = "Z+";
  b.index = 1, b.t_start_s = 4, b.t_end_s = 5, b.face = "Z+", b.used = false, b.reason = "moved";
  PosePair p;
  p.pose_a = 0, p.pose_b = 1, p.face = "Z+", p.rotation_deg = 91, p.reason = "turned 91";
  ASSERT_OK(store_->SavePoses("S1", {a}, {}));
  ASSERT_OK(store_->SavePoses("S1", {a, b}, {p}));  // a replay rewrites the same rows
  ASSERT_OK_AND_ASSIGN(std::vector<Pose> poses, store_->ListPoses("S1"));
  ASSERT_EQ(poses.size(), 2u);
  EXPECT_EQ(poses[1].face, "Z+");
  EXPECT_EQ(poses[1].reason, "moved");
  EXPECT_EQ(store_->GetSession("S1").value().poses_accepted, 1);
  ASSERT_OK_AND_ASSIGN(std::vector<PosePair> pairs, store_->ListPairs("S1"));
  ASSERT_EQ(pairs.size(), 1u);
  EXPECT_EQ(pairs[0].rotation_deg, 91);
  EXPECT_FALSE(pairs[0].ok);
  PosePair bad = p;
  bad.pose_b = 0;
  EXPECT_EQ(store_->SavePoses("S1", {}, {bad}).code(), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(store_->SavePoses("nope", {a}, {}).code(), absl::StatusCode::kNotFound);
}

}  // namespace
}  // namespace imucal::storage
