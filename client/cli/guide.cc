// `imucal guide`: the technician's live guidance over a session's WatchSession events. The
// samples come from the robot (its SDK Uploader, or `imucal upload`); the guide only watches,
// says what to do next, and starts the solve when the protocol is complete and the robot's
// upload has ended (the server refuses a solve while a stream of the session is open: it would
// cut the capture short).
#include <unistd.h>

#include <chrono>
#include <condition_variable>
#include <cstdio>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "client/cli/args.h"
#include "client/cli/command_table.h"
#include "client/cli/commands.h"
#include "client/cli/guide_view.h"
#include "client/cli/server_common.h"
#include "client/sdk/grpc_status.h"

namespace imucal::cli {
namespace {

namespace pb = imucal::v1;

constexpr char kGuideHelp[] =
    "usage: imucal guide --device D [--protocol six-face|positions|free|ferraris|auto] [--session "
    "S]\n"
    "  Guides a calibration capture: opens a session for the device (or follows --session S),\n"
    "  then, while the robot streams its samples (e.g. `imucal upload FILE --device D`), says\n"
    "  which pose comes next, shows whether the robot is still and for how long it must hold,\n"
    "  each pose and 180-degree pair's verdict (with what to redo), the progress, and at the end\n"
    "  the solve result and verdict.\n"
    "options:\n"
    "  --protocol P       six-face (default): faces and 180-degree pairs; positions: the 24\n"
    "                     positions (faces and edges); free: hand-held (faces and corners);\n"
    "                     ferraris, auto: no target, so the guide shows poses but never solves\n"
    "  --no-solve         do not start the solve when the protocol is complete (else it starts\n"
    "                     once the robot's upload has ended, the guide saying it waits for it)\n"
    "  --seed N           BSAS seed for the solve\n"
    "  --reconnects N     re-open the event stream at most N times if it drops (default 5)\n"
    "  --server ADDR      the calibration service (default $IMUCAL_SERVER, else 127.0.0.1:50051)\n"
    "exit codes: 0 verdict pass/warn, 1 usage, 2 unknown device/session, 3 solve failed or\n"
    "            session cancelled, 4 verdict fail, 5 internal, 6 server unreachable\n";

int ExitFor(const pb::SolveJob& job) {
  if (job.state() == pb::JOB_STATE_FAILED) return kExitUndetermined;
  return ExitForVerdict(VerdictOf(job.verdict_kind(), job.verdict()));
}

// Starts the session's solve once the protocol is complete and no stream of the session is open
// (Session.open_streams): the robot's upload goes on after the last pose (its trailing samples),
// and a solve would end it with the rest of the capture unstored. Meanwhile it says that it waits
// and how far the upload has come. Runs on a thread of its own, reading GetSession every
// kPoll: the upload's end is another client's stream ending, which no call of the guide's can
// wait on (the watch's events stop with the samples).
class SolveWhenUploaded {
 public:
  static constexpr auto kPoll = std::chrono::milliseconds(500);
  static constexpr auto kProgressEvery = std::chrono::seconds(2);

  // `view` is shared with the event loop, under `view_mu`.
  SolveWhenUploaded(const Server& server, std::string session_id, uint64_t seed, GuideView* view,
                    std::mutex* view_mu)
      : server_(server),
        session_id_(std::move(session_id)),
        seed_(seed),
        view_(view),
        view_mu_(view_mu) {}
  ~SolveWhenUploaded() { Stop(); }

  void Begin() {  // once; from the event loop, view_mu held
    if (thread_.joinable()) return;
    thread_ = std::thread([this] { Run(); });
  }
  void Stop() {
    {
      std::lock_guard lock(mu_);
      stopping_ = true;
    }
    cv_.notify_all();
    if (thread_.joinable()) thread_.join();
  }
  std::string job_id() {
    std::lock_guard lock(mu_);
    return job_id_;
  }

 private:
  void Say(const std::string& text) {
    std::lock_guard lock(*view_mu_);
    view_->Line(text);
  }

  void Run() {
    bool said_waiting = false;
    auto last_said = std::chrono::steady_clock::now();
    int64_t last_samples = -1;
    for (;;) {
      {
        std::unique_lock lock(mu_);
        if (stopping_) return;
      }
      pb::Session now;
      grpc::Status got = GetSession(server_, session_id_, &now);
      if (got.ok() && now.open_streams() == 0) {
        if (now.state() != pb::SESSION_STATE_OPEN) return;  // solved or cancelled meanwhile
        pb::SolveSessionRequest solve;
        solve.set_session_id(session_id_);
        solve.set_seed(seed_);
        pb::SolveJob job;
        auto ctx = CallContext();
        // The view held through the call: the solve's events, which the watch may bring first,
        // are shown after the line that starts it.
        std::unique_lock view_lock(*view_mu_);
        grpc::Status s = server_.sessions->SolveSession(ctx.get(), solve, &job);
        if (s.ok()) {
          {
            std::lock_guard lock(mu_);
            job_id_ = job.id();
          }
          view_->Line(absl::StrCat(said_waiting ? "upload complete: " : "protocol complete: ",
                                   "starting the solve (job ", job.id(), ") on ", now.samples(),
                                   " samples"));
          return;
        }
        view_lock.unlock();
        // A stream opened meanwhile (the robot resumed): wait for it too.
        if (s.error_code() != grpc::StatusCode::FAILED_PRECONDITION ||
            s.error_message().find("stream") == std::string::npos) {
          Say(absl::StrCat("could not start the solve: ", s.error_message()));
          return;
        }
      } else if (got.ok()) {
        const auto t = std::chrono::steady_clock::now();
        if (!said_waiting) {
          Say(absl::StrFormat(
              "protocol complete: waiting for the robot's upload to finish before solving "
              "(%d samples stored so far, %d stream%s open)",
              now.samples(), now.open_streams(), now.open_streams() == 1 ? "" : "s"));
          said_waiting = true;
          last_said = t;
          last_samples = now.samples();
        } else if (t - last_said >= kProgressEvery && now.samples() != last_samples) {
          Say(absl::StrFormat("waiting for the upload: %d samples stored", now.samples()));
          last_said = t;
          last_samples = now.samples();
        }
      }
      std::unique_lock lock(mu_);
      cv_.wait_for(lock, kPoll, [this] { return stopping_; });
    }
  }

  const Server& server_;
  const std::string session_id_;
  const uint64_t seed_;
  GuideView* view_;
  std::mutex* view_mu_;
  std::mutex mu_;
  std::condition_variable cv_;
  bool stopping_ = false;  // guarded by mu_
  std::string job_id_;     // guarded by mu_
  std::thread thread_;
};

// The session to guide: --session's, else a new one for --device. kExitOk, or the exit code.
int OpenOrFollowSession(const Args& a, const Server& server, pb::Session* session) {
  if (auto session_id = a.Get("session")) {
    if (grpc::Status s = GetSession(server, *session_id, session); !s.ok())
      return RpcError(server, s);
    return kExitOk;
  }
  // six-face unless told: a guide must know what to ask for (auto sets no target).
  auto protocol = ParseProtocol(a.Get("protocol").value_or("six-face"));
  if (!protocol.ok()) return UsageError(std::string(protocol.status().message()), kGuideHelp);
  if (grpc::Status s = CreateSession(server, *a.Get("device"), *protocol, 0.0, session); !s.ok())
    return RpcError(server, s);
  return kExitOk;
}

// Shows the session's events (WatchSession) until the view says the session is done or the
// server ends the stream (OK), re-opening a dropped watch up to `reconnects` times in a row (else
// its error). Begins `solver` once the protocol is complete, when `solve`.
grpc::Status FollowEvents(const Server& server, const std::string& session_id, int64_t reconnects,
                          bool solve, GuideView* view, std::mutex* view_mu,
                          SolveWhenUploaded* solver) {
  bool done = false;
  int drops = 0;
  while (!done) {
    grpc::ClientContext context;
    // Every call has a deadline: a watch is re-opened (with a fresh snapshot) after an hour.
    context.set_deadline(std::chrono::system_clock::now() + std::chrono::hours(1));
    pb::WatchSessionRequest req;
    req.set_session_id(session_id);
    auto stream = server.sessions->WatchSession(&context, req);
    pb::SessionEvent event;
    bool got_event = false;
    while (!done && stream->Read(&event)) {
      got_event = true;
      std::lock_guard lock(*view_mu);
      done = view->OnEvent(event);
      if (!done && view->ReadyToSolve() && solve) solver->Begin();
    }
    if (done) context.TryCancel();
    const grpc::Status status = stream->Finish();
    if (done || status.ok()) break;  // status OK: the server ended the stream (session closed)
    if (got_event) drops = 0;
    if (!sdk::IsUnreachable(sdk::FromGrpcStatus(status)) || ++drops > reconnects) return status;
    {
      std::lock_guard lock(*view_mu);
      view->Line(absl::StrCat("connection lost (", status.error_message(), "), reconnecting..."));
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(200 << std::min(drops, 5)));
  }
  return grpc::Status::OK;
}

// Polls solve job `job_id` until it is done or failed, into `job`.
grpc::Status AwaitSolveJob(const Server& server, const std::string& job_id, pb::SolveJob* job) {
  auto interval = std::chrono::milliseconds(50);
  for (;;) {
    pb::GetSolveJobRequest req;
    req.set_job_id(job_id);
    auto ctx = CallContext();
    if (grpc::Status s = server.sessions->GetSolveJob(ctx.get(), req, job); !s.ok()) return s;
    if (job->state() == pb::JOB_STATE_DONE || job->state() == pb::JOB_STATE_FAILED)
      return grpc::Status::OK;
    std::this_thread::sleep_for(interval);
    interval = std::min(interval * 2, std::chrono::milliseconds(1000));
  }
}

}  // namespace

int RunGuide(const std::vector<std::string>& argv) {
  auto a = ParseCommandFlags("guide", argv);
  if (!a.ok()) return UsageError(std::string(a.status().message()), kGuideHelp);
  if (a->Has("help")) return std::printf("%s", kGuideHelp), kExitOk;
  if (!a->Get("device") && !a->Get("session"))
    return UsageError("guide needs --device or --session", kGuideHelp);
  auto seed = a->GetInt("seed", 0);
  auto reconnects = a->GetInt("reconnects", 5);
  if (!seed.ok() || !reconnects.ok())
    return UsageError("--seed and --reconnects take numbers", kGuideHelp);
  Server server = Connect(*a);
  pb::Session session;
  if (int code = OpenOrFollowSession(*a, server, &session); code != kExitOk) return code;

  GuideView view(::isatty(STDOUT_FILENO) == 1, [](const std::string& text) {
    std::fputs(text.c_str(), stdout);
    std::fflush(stdout);
  });
  view.Line(absl::StrFormat("Calibrating %s: session %s (protocol %s).", session.device_id(),
                            session.id(), ProtocolName(session.protocol())));
  view.Line(
      absl::StrFormat("Start the robot's capture now; it streams into session %s "
                      "(e.g. imucal upload FILE --session %s).",
                      session.id(), session.id()));

  std::mutex view_mu;  // the view is written by the event loop and by the solver's thread
  SolveWhenUploaded solver(server, session.id(), static_cast<uint64_t>(*seed), &view, &view_mu);
  if (grpc::Status s = FollowEvents(server, session.id(), *reconnects, !a->Has("no-solve"), &view,
                                    &view_mu, &solver);
      !s.ok()) {
    solver.Stop();
    return RpcError(server, s);
  }
  solver.Stop();
  const std::string job_id = solver.job_id();

  // The stream ended without the solve's result (a server that does not send it): ask for it.
  pb::SolveJob job = view.final_job();
  if (job.id().empty() && !job_id.empty()) {
    job.set_id(job_id);
    if (grpc::Status s = AwaitSolveJob(server, job_id, &job); !s.ok()) return RpcError(server, s);
    pb::SessionEvent result;
    *result.mutable_solve() = job;
    view.OnEvent(result);
  }
  if (view.session().state() == pb::SESSION_STATE_CANCELLED) return kExitUndetermined;
  if (job.id().empty()) {
    view.Line(absl::StrFormat("session %s closed (%s) without a solve result", session.id(),
                              SessionStateName(view.session().state())));
    return kExitUndetermined;
  }
  view.Line(absl::StrFormat("Full report: imucal report --session %s", session.id()));
  return ExitFor(job);
}

}  // namespace imucal::cli
