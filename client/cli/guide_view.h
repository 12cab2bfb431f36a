// The technician's guidance text for `imucal guide`, built from WatchSession events. Separate
// from the RPC loop (guide.cc) so that it can be tested by feeding it events.
//
// On a terminal (`interactive`), the live stillness indicator is one status line redrawn with
// "\r" (and ESC[K to clear the rest); every other message is a permanent line printed above it.
// Otherwise (a pipe, a log) the status line is not drawn: stillness changes are printed as
// plain lines only when they change (moving -> still, pose captured), so logs stay readable.
#ifndef IMUCAL_CLIENT_CLI_GUIDE_VIEW_H_
#define IMUCAL_CLIENT_CLI_GUIDE_VIEW_H_

#include <functional>
#include <string>

#include "imucal/v1/imucal.pb.h"

namespace imucal::cli {

class GuideView {
 public:
  // `write` receives the text to output, in order (e.g. fputs to stdout and fflush).
  GuideView(bool interactive, std::function<void(const std::string&)> write);

  // Renders one event. Returns true when the guidance is over: the solve finished (done or
  // failed) or the session closed without a solve (cancelled).
  bool OnEvent(const imucal::v1::SessionEvent& event);

  // Protocol complete (poses_accepted >= poses_wanted > 0) and no solve seen yet.
  bool ReadyToSolve() const;
  bool solve_seen() const { return solve_seen_; }
  // The finished solve job (state DONE/FAILED), if one was seen.
  const imucal::v1::SolveJob& final_job() const { return final_job_; }
  const imucal::v1::Session& session() const { return session_; }

  // Prints a permanent line (clearing the status line first on a terminal).
  void Line(const std::string& text);

 private:
  void Status(const std::string& text);
  void OnStillness(const imucal::v1::Stillness& s);
  void OnPose(const imucal::v1::PoseEvent& p);
  void OnNextPose(const imucal::v1::NextPose& n);
  void OnPair(const imucal::v1::PairVerdict& p);
  void OnProgress(const imucal::v1::Progress& p);
  bool OnSolve(const imucal::v1::SolveJob& job);
  bool OnSession(const imucal::v1::Session& s);

  bool interactive_;
  std::function<void(const std::string&)> write_;
  bool status_shown_ = false;
  int last_still_state_ = -1;  // -1 unknown, 0 moving, 1 still, 2 held long enough
  std::string last_instruction_;
  std::string last_progress_;
  imucal::v1::Progress progress_;
  imucal::v1::Session session_;
  imucal::v1::SolveJob final_job_;
  bool solve_seen_ = false;
  std::string last_solve_state_;
};

}  // namespace imucal::cli

#endif  // IMUCAL_CLIENT_CLI_GUIDE_VIEW_H_
