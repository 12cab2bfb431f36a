#include "client/cli/guide_view.h"

#include <algorithm>
#include <cmath>
#include <utility>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"
#include "client/cli/server_common.h"

namespace imucal::cli {

namespace pb = imucal::v1;

GuideView::GuideView(bool interactive, std::function<void(const std::string&)> write)
    : interactive_(interactive), write_(std::move(write)) {}

void GuideView::Line(const std::string& text) {
  if (status_shown_) write_("\r\033[K");
  status_shown_ = false;
  write_(text + "\n");
}

void GuideView::Status(const std::string& text) {
  if (!interactive_) return;
  write_(absl::StrCat("\r\033[K", text));
  status_shown_ = true;
}

bool GuideView::OnEvent(const pb::SessionEvent& event) {
  switch (event.event_case()) {
    case pb::SessionEvent::kStillness:
      OnStillness(event.stillness());
      return false;
    case pb::SessionEvent::kPose:
      OnPose(event.pose());
      return false;
    case pb::SessionEvent::kNextPose:
      OnNextPose(event.next_pose());
      return false;
    case pb::SessionEvent::kPair:
      OnPair(event.pair());
      return false;
    case pb::SessionEvent::kProgress:
      OnProgress(event.progress());
      return false;
    case pb::SessionEvent::kSolve:
      return OnSolve(event.solve());
    case pb::SessionEvent::kSession:
      return OnSession(event.session());
    default:
      return false;
  }
}

bool GuideView::ReadyToSolve() const {
  return !solve_seen_ && progress_.poses_wanted() > 0 &&
         progress_.poses_accepted() >= progress_.poses_wanted() &&
         session_.state() == pb::SESSION_STATE_OPEN;
}

void GuideView::OnStillness(const pb::Stillness& s) {
  const double needed = s.needed_s() > 0 ? s.needed_s() : 1.0;
  int state = 0;
  if (s.still()) state = s.still_for_s() >= needed ? 2 : 1;
  if (interactive_) {
    const int width = 20;
    const int filled = std::clamp(static_cast<int>(width * s.still_for_s() / needed), 0, width);
    std::string text;
    if (state == 0) {
      text = absl::StrFormat("MOVING   (motion x%.1f)  put the robot down and keep it still",
                             s.motion_ratio());
    } else if (state == 1) {
      text = absl::StrFormat("HOLD STILL [%s%s] %.1f s left", std::string(filled, '#'),
                             std::string(width - filled, '.'), needed - s.still_for_s());
    } else {
      text = absl::StrFormat("STILL    [%s] %.1f s held: long enough for this pose",
                             std::string(width, '#'), s.still_for_s());
    }
    Status(text);
  } else if (state != last_still_state_) {
    if (state == 0) Line("moving");
    if (state == 1) Line(absl::StrFormat("still: hold for %.0f s", needed));
    if (state == 2) Line(absl::StrFormat("held still for %.1f s", s.still_for_s()));
  }
  last_still_state_ = state;
}

void GuideView::OnPose(const pb::PoseEvent& p) {
  const std::string face = p.face().empty() ? "" : absl::StrCat(" (", p.face(), ")");
  if (p.accepted()) {
    Line(absl::StrFormat("[ok]   pose %d captured%s, %.1f-%.1f s", p.index(), face, p.t_start_s(),
                         p.t_end_s()));
  } else {
    Line(absl::StrFormat("[redo] pose %d%s rejected: %s", p.index(), face, p.reason()));
    Line("       -> do this pose again");
  }
}

void GuideView::OnNextPose(const pb::NextPose& n) {
  std::string text = absl::StrCat("NEXT: ", n.instruction());
  // A face is one axis ("Y+"); the positions and free protocols also ask for cube edges and
  // corners ("X+Z+", "X+Y-Z+"), which are directions rather than faces.
  if (!n.face().empty())
    absl::StrAppend(&text, n.face().size() == 2 ? "  [face " : "  [up ", n.face(), "]");
  if (n.turn_half()) absl::StrAppend(&text, "  (turn it 180 degrees about the vertical)");
  if (text == last_instruction_) return;  // repeated in snapshots
  last_instruction_ = text;
  Line(text);
}

void GuideView::OnPair(const pb::PairVerdict& p) {
  const std::string face = p.face().empty() ? "" : absl::StrCat(" ", p.face());
  if (p.ok()) {
    Line(absl::StrFormat("[ok]   pair%s (poses %d, %d): turn %.1f deg, tilt %.1f deg", face,
                         p.pose_a(), p.pose_b(), p.rotation_deg(), p.tilt_deg()));
  } else {
    Line(absl::StrFormat("[redo] pair%s (poses %d, %d) FAILED: %s", face, p.pose_a(), p.pose_b(),
                         p.reason().empty() ? "rejected" : p.reason()));
    Line(
        absl::StrFormat("       -> REDO%s: put it back on%s, half a turn about the vertical "
                        "from pose %d, and hold it still",
                        face, face, p.pose_a()));
  }
}

void GuideView::OnProgress(const pb::Progress& p) {
  progress_ = p;
  std::string text =
      p.poses_wanted() > 0
          ? absl::StrFormat("progress: %d/%d poses", p.poses_accepted(), p.poses_wanted())
          : absl::StrFormat("progress: %d poses", p.poses_accepted());
  if (p.faces_done_size() > 0 || p.faces_pending_size() > 0) {
    const bool six_face = session_.protocol() == pb::PROTOCOL_SIX_FACE;
    absl::StrAppend(&text, six_face ? "; faces done: " : "; directions done: ",
                    p.faces_done().empty() ? "none" : absl::StrJoin(p.faces_done(), " "));
    if (!p.faces_pending().empty())
      absl::StrAppend(&text, "; to do: ", absl::StrJoin(p.faces_pending(), " "));
  }
  if (p.coverage() > 0)
    absl::StrAppend(&text, absl::StrFormat("; coverage %.0f%%", 100 * p.coverage()));
  if (text == last_progress_) return;
  last_progress_ = text;
  Line(text);
}

bool GuideView::OnSolve(const pb::SolveJob& job) {
  solve_seen_ = true;
  const std::string state = JobStateName(job.state());
  if (job.state() == pb::JOB_STATE_DONE) {
    final_job_ = job;
    Line(absl::StrFormat(
        "RESULT: version %d, verdict %s, %s", job.version(), job.verdict(),
        job.activated() ? "now active" : "candidate, not activated (see imucal report)"));
    return true;
  }
  if (job.state() == pb::JOB_STATE_FAILED) {
    final_job_ = job;
    Line(absl::StrCat("RESULT: the solve failed: ", job.error()));
    return true;
  }
  if (state != last_solve_state_) Line(absl::StrCat("solving (", state, ")..."));
  last_solve_state_ = state;
  return false;
}

bool GuideView::OnSession(const pb::Session& s) {
  const bool changed = s.state() != session_.state();
  session_ = s;
  if (!changed) return false;
  switch (s.state()) {
    case pb::SESSION_STATE_OPEN:
      Line(absl::StrFormat("session %s for %s (%s): %lld samples, %d poses so far", s.id(),
                           s.device_id(), ProtocolName(s.protocol()),
                           static_cast<long long>(s.samples()), s.poses_accepted()));
      return false;
    case pb::SESSION_STATE_SOLVING:
      if (!solve_seen_) Line("solving...");  // else the solve job's events already say so
      return false;
    case pb::SESSION_STATE_CANCELLED:
      Line(absl::StrCat("session ", s.id(), " was cancelled"));
      return true;
    case pb::SESSION_STATE_SOLVED:
    case pb::SESSION_STATE_FAILED:
      // The solve event carries the result; if it never comes, the stream's end stops the guide.
      return false;
    default:
      return false;
  }
}

}  // namespace imucal::cli
