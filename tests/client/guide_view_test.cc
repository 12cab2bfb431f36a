// GuideView: the technician's text for a sequence of WatchSession events, on a terminal (one
// status line redrawn with \r) and in a log (plain lines, stillness only when it changes).
#include "client/cli/guide_view.h"

#include <gtest/gtest.h>

#include <string>

namespace imucal::cli {
namespace {

namespace pb = imucal::v1;

pb::SessionEvent Still(bool still, double for_s) {
  pb::SessionEvent e;
  e.mutable_stillness()->set_still(still);
  e.mutable_stillness()->set_still_for_s(for_s);
  e.mutable_stillness()->set_needed_s(4.0);
  e.mutable_stillness()->set_motion_ratio(still ? 0.3 : 3.0);
  return e;
}

pb::SessionEvent Next(const std::string& instruction, const std::string& face, bool turn) {
  pb::SessionEvent e;
  e.mutable_next_pose()->set_instruction(instruction);
  e.mutable_next_pose()->set_face(face);
  e.mutable_next_pose()->set_turn_half(turn);
  return e;
}

pb::SessionEvent Pair(bool ok, const std::string& reason) {
  pb::SessionEvent e;
  pb::PairVerdict* p = e.mutable_pair();
  p->set_pose_a(2);
  p->set_pose_b(3);
  p->set_ok(ok);
  p->set_face("Y+");
  p->set_rotation_deg(ok ? 179.5 : 120.0);
  p->set_reason(reason);
  return e;
}

pb::SessionEvent Progress(int accepted, int wanted) {
  pb::SessionEvent e;
  e.mutable_progress()->set_poses_accepted(accepted);
  e.mutable_progress()->set_poses_wanted(wanted);
  e.mutable_progress()->add_faces_done("Z+");
  e.mutable_progress()->add_faces_pending("Y+");
  return e;
}

pb::SessionEvent Solve(pb::JobState state, const std::string& verdict) {
  pb::SessionEvent e;
  e.mutable_solve()->set_id("j-1");
  e.mutable_solve()->set_state(state);
  e.mutable_solve()->set_version(3);
  e.mutable_solve()->set_verdict(verdict);
  e.mutable_solve()->set_activated(verdict != "fail");
  return e;
}

pb::SessionEvent OpenSession() {
  pb::SessionEvent e;
  e.mutable_session()->set_id("s-1");
  e.mutable_session()->set_device_id("robot-1");
  e.mutable_session()->set_state(pb::SESSION_STATE_OPEN);
  e.mutable_session()->set_protocol(pb::PROTOCOL_SIX_FACE);
  return e;
}

TEST(GuideViewTest, LogModePrintsPlainLinesAndStillnessChangesOnly) {
  std::string out;
  GuideView view(false, [&](const std::string& s) { out += s; });
  EXPECT_FALSE(view.OnEvent(OpenSession()));
  EXPECT_FALSE(view.OnEvent(Next("Lay the robot on its right side", "Y+", false)));
  EXPECT_FALSE(view.OnEvent(Still(false, 0)));
  EXPECT_FALSE(view.OnEvent(Still(true, 1.0)));
  EXPECT_FALSE(view.OnEvent(Still(true, 2.0)));  // no new line: same state
  EXPECT_FALSE(view.OnEvent(Still(true, 4.2)));
  EXPECT_EQ(out.find('\r'), std::string::npos) << out;
  EXPECT_NE(out.find("NEXT: Lay the robot on its right side  [face Y+]\n"), std::string::npos);
  EXPECT_NE(out.find("moving\n"), std::string::npos) << out;
  EXPECT_NE(out.find("still: hold for 4 s\n"), std::string::npos) << out;
  EXPECT_EQ(out.find("still: hold for 4 s\n"), out.rfind("still: hold for 4 s\n")) << out;
  EXPECT_NE(out.find("held still for 4.2 s\n"), std::string::npos) << out;
}

TEST(GuideViewTest, TerminalModeRedrawsTheStatusLine) {
  std::string out;
  GuideView view(true, [&](const std::string& s) { out += s; });
  view.OnEvent(Still(true, 1.0));
  view.OnEvent(Still(true, 3.0));
  EXPECT_NE(out.find("\r\033[KHOLD STILL [#####...............] 3.0 s left"), std::string::npos)
      << out;
  EXPECT_EQ(out.find('\n'), std::string::npos) << out;  // only the status line so far
  view.OnEvent(Next("Turn it 180 degrees", "Y+", true));
  // A permanent line first clears the status line.
  EXPECT_NE(out.find("\r\033[KNEXT: Turn it 180 degrees  [face Y+]  (turn it 180 degrees"),
            std::string::npos)
      << out;
}

TEST(GuideViewTest, FailedPairAsksForARedo) {
  std::string out;
  GuideView view(false, [&](const std::string& s) { out += s; });
  view.OnEvent(Pair(true, ""));
  view.OnEvent(Pair(false, "turned 120 degrees, not 180"));
  EXPECT_NE(out.find("[ok]   pair Y+ (poses 2, 3): turn 179.5 deg"), std::string::npos) << out;
  EXPECT_NE(out.find("[redo] pair Y+ (poses 2, 3) FAILED: turned 120 degrees, not 180"),
            std::string::npos)
      << out;
  EXPECT_NE(out.find("-> REDO Y+"), std::string::npos) << out;
}

TEST(GuideViewTest, ProgressThenSolveResultEndsTheGuide) {
  std::string out;
  GuideView view(false, [&](const std::string& s) { out += s; });
  view.OnEvent(OpenSession());
  view.OnEvent(Progress(11, 12));
  EXPECT_FALSE(view.ReadyToSolve());
  view.OnEvent(Progress(12, 12));
  EXPECT_TRUE(view.ReadyToSolve());
  EXPECT_NE(out.find("progress: 12/12 poses; faces done: Z+; to do: Y+"), std::string::npos) << out;
  EXPECT_FALSE(view.OnEvent(Solve(pb::JOB_STATE_RUNNING, "")));
  EXPECT_FALSE(view.ReadyToSolve());
  EXPECT_TRUE(view.OnEvent(Solve(pb::JOB_STATE_DONE, "pass")));
  EXPECT_NE(out.find("RESULT: version 3, verdict pass, now active"), std::string::npos) << out;
  EXPECT_EQ(view.final_job().verdict(), "pass");
}

TEST(GuideViewTest, RejectedPoseSaysWhyAndToRedo) {
  std::string out;
  GuideView view(false, [&](const std::string& s) { out += s; });
  pb::SessionEvent e;
  e.mutable_pose()->set_index(4);
  e.mutable_pose()->set_accepted(false);
  e.mutable_pose()->set_reason("moved during capture");
  view.OnEvent(e);
  EXPECT_NE(out.find("[redo] pose 4 rejected: moved during capture"), std::string::npos) << out;
  EXPECT_NE(out.find("do this pose again"), std::string::npos) << out;
}

TEST(GuideViewTest, CancelledSessionEndsTheGuide) {
  std::string out;
  GuideView view(false, [&](const std::string& s) { out += s; });
  view.OnEvent(OpenSession());
  pb::SessionEvent e = OpenSession();
  e.mutable_session()->set_state(pb::SESSION_STATE_CANCELLED);
  EXPECT_TRUE(view.OnEvent(e));
  EXPECT_NE(out.find("session s-1 was cancelled"), std::string::npos) << out;
}

}  // namespace
}  // namespace imucal::cli
