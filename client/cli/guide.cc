// `imucal guide`: the technician's live guidance over a session's WatchSession events. The
// samples come from the robot (its SDK Uploader, or `imucal upload`); the guide only watches,
// says what to do next, and starts the solve when the protocol is complete.
#include <unistd.h>

#include <chrono>
#include <cstdio>
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
    "  --no-solve         do not start the solve when the protocol is complete\n"
    "  --seed N           BSAS seed for the solve\n"
    "  --reconnects N     re-open the event stream at most N times if it drops (default 5)\n"
    "  --server ADDR      the calibration service (default $IMUCAL_SERVER, else 127.0.0.1:50051)\n"
    "exit codes: 0 verdict pass/warn, 1 usage, 2 unknown device/session, 3 solve failed or\n"
    "            session cancelled, 4 verdict fail, 5 internal, 6 server unreachable\n";

int ExitFor(const pb::SolveJob& job) {
  if (job.state() == pb::JOB_STATE_FAILED) return kExitUndetermined;
  return ExitForVerdict(job.verdict());
}

}  // namespace

int RunGuide(const std::vector<std::string>& argv) {
  auto a = ParseCommandFlags("guide", argv);
  if (!a.ok()) return UsageError(std::string(a.status().message()), kGuideHelp);
  if (a->Has("help")) return std::printf("%s", kGuideHelp), kExitOk;
  auto device = a->Get("device");
  auto session_id = a->Get("session");
  if (!device && !session_id) return UsageError("guide needs --device or --session", kGuideHelp);
  auto seed = a->GetInt("seed", 0);
  auto reconnects = a->GetInt("reconnects", 5);
  if (!seed.ok() || !reconnects.ok())
    return UsageError("--seed and --reconnects take numbers", kGuideHelp);
  Server server = Connect(*a);

  pb::Session session;
  if (session_id) {
    if (grpc::Status s = GetSession(server, *session_id, &session); !s.ok())
      return RpcError(server, s);
  } else {
    // six-face unless told: a guide must know what to ask for (auto sets no target).
    auto protocol = ParseProtocol(a->Get("protocol").value_or("six-face"));
    if (!protocol.ok()) return UsageError(std::string(protocol.status().message()), kGuideHelp);
    if (grpc::Status s = CreateSession(server, *device, *protocol, 0.0, &session); !s.ok())
      return RpcError(server, s);
  }

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

  std::string job_id;
  bool done = false;
  int drops = 0;
  while (!done) {
    grpc::ClientContext context;
    // Every call has a deadline: a watch is re-opened (with a fresh snapshot) after an hour.
    context.set_deadline(std::chrono::system_clock::now() + std::chrono::hours(1));
    pb::WatchSessionRequest req;
    req.set_session_id(session.id());
    auto stream = server.sessions->WatchSession(&context, req);
    pb::SessionEvent event;
    bool got_event = false;
    while (!done && stream->Read(&event)) {
      got_event = true;
      done = view.OnEvent(event);
      if (!done && view.ReadyToSolve() && job_id.empty() && !a->Has("no-solve")) {
        pb::SolveSessionRequest solve;
        solve.set_session_id(session.id());
        solve.set_seed(static_cast<uint64_t>(*seed));
        pb::SolveJob job;
        auto ctx = CallContext();
        if (grpc::Status s = server.sessions->SolveSession(ctx.get(), solve, &job); !s.ok()) {
          view.Line(absl::StrCat("could not start the solve: ", s.error_message()));
        } else {
          job_id = job.id();
          view.Line(absl::StrCat("protocol complete: starting the solve (job ", job.id(), ")"));
        }
      }
    }
    if (done) context.TryCancel();
    const grpc::Status status = stream->Finish();
    if (done) break;
    if (status.ok()) break;  // the server ended the stream: the session is closed
    if (got_event) drops = 0;
    if (!sdk::IsUnreachable(sdk::FromGrpcStatus(status)) || ++drops > *reconnects)
      return RpcError(server, status);
    view.Line(absl::StrCat("connection lost (", status.error_message(), "), reconnecting..."));
    std::this_thread::sleep_for(std::chrono::milliseconds(200 << std::min(drops, 5)));
  }

  // The stream ended without the solve's result (a server that does not send it): ask for it.
  pb::SolveJob job = view.final_job();
  if (job.id().empty() && !job_id.empty()) {
    job.set_id(job_id);
    auto interval = std::chrono::milliseconds(50);
    for (;;) {
      pb::GetSolveJobRequest req;
      req.set_job_id(job_id);
      auto ctx = CallContext();
      if (grpc::Status s = server.sessions->GetSolveJob(ctx.get(), req, &job); !s.ok())
        return RpcError(server, s);
      if (job.state() == pb::JOB_STATE_DONE || job.state() == pb::JOB_STATE_FAILED) break;
      std::this_thread::sleep_for(interval);
      interval = std::min(interval * 2, std::chrono::milliseconds(1000));
    }
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
