// `imucal solve`: start a session's solve job and, with --wait, follow it to its verdict
// (SolveAndMaybeWait, which `upload --solve` shares).
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <string>
#include <thread>
#include <vector>

#include "client/cli/args.h"
#include "client/cli/command_table.h"
#include "client/cli/commands.h"
#include "client/cli/server_common.h"

namespace imucal::cli {

namespace pb = imucal::v1;

namespace {

constexpr char kSolveHelp[] =
    "usage: imucal solve --session S [--wait] [--force] [--seed N] [--timeout SECONDS] [--json]\n"
    "  Starts a solve job for the session's samples. With --wait, waits for the result and\n"
    "  prints the version created, its verdict and whether it became active. A session whose\n"
    "  robot is still uploading (a sample stream open) is not solved: the server says so.\n"
    "options:\n"
    "  --force            solve even while a stream is open: the upload is ended and the rest\n"
    "                     of its capture is not stored\n";

}  // namespace

int SolveAndMaybeWait(const Server& server, const std::string& session, uint64_t seed, bool wait,
                      double timeout_s, bool as_json, bool force) {
  pb::SolveSessionRequest req;
  req.set_session_id(session);
  req.set_seed(seed);
  req.set_force(force);
  pb::SolveJob job;
  {
    auto ctx = CallContext();
    grpc::Status s = server.sessions->SolveSession(ctx.get(), req, &job);
    // Already solving (this command ran before, and lost its server or was stopped): with
    // --wait, follow the running job rather than fail.
    pb::Session now;
    if (!s.ok() && s.error_code() == grpc::StatusCode::FAILED_PRECONDITION && wait) {
      pb::GetSessionRequest get;
      get.set_session_id(session);
      auto again = CallContext();
      if (server.sessions->GetSession(again.get(), get, &now).ok() &&
          now.state() == pb::SESSION_STATE_SOLVING && !now.solve_job_id().empty()) {
        std::fprintf(stderr, "imucal: session %s is already being solved: waiting for job %s\n",
                     session.c_str(), now.solve_job_id().c_str());
        job.set_id(now.solve_job_id());
        job.set_session_id(session);
        job.set_state(pb::JOB_STATE_RUNNING);
        s = grpc::Status::OK;
      }
    }
    if (!s.ok()) return RpcError(server, s);
  }
  const auto deadline =
      std::chrono::steady_clock::now() + std::chrono::milliseconds(int64_t(timeout_s * 1000));
  // A poll with a growing interval: solves take from a fraction of a second to minutes.
  auto interval = std::chrono::milliseconds(50);
  bool lost_server = false;
  while (wait && (job.state() == pb::JOB_STATE_QUEUED || job.state() == pb::JOB_STATE_RUNNING ||
                  job.state() == pb::JOB_STATE_UNSPECIFIED)) {
    if (std::chrono::steady_clock::now() > deadline) {
      std::fprintf(stderr, "imucal: solve job %s still %s after %.0f s\n", job.id().c_str(),
                   JobStateName(job.state()).c_str(), timeout_s);
      return kExitUnavailable;
    }
    std::this_thread::sleep_for(interval);
    interval = std::min(interval * 2, std::chrono::milliseconds(1000));
    pb::GetSolveJobRequest get;
    get.set_job_id(job.id());
    auto ctx = CallContext();
    ctx->set_wait_for_ready(true);  // through a restart, or on to another replica
    pb::SolveJob now;
    if (grpc::Status s = server.sessions->GetSolveJob(ctx.get(), get, &now); !s.ok()) {
      // The server that runs the job stopped: the job lives on in storage, and another replica
      // (or the same one, restarted) runs it again (README "Scaling out"). Ask until the
      // timeout.
      if (s.error_code() != grpc::StatusCode::UNAVAILABLE &&
          s.error_code() != grpc::StatusCode::DEADLINE_EXCEEDED)
        return RpcError(server, s);
      if (!lost_server) {
        std::fprintf(stderr, "imucal: lost %s (%s); still waiting for job %s\n",
                     server.address.c_str(), s.error_message().c_str(), job.id().c_str());
        lost_server = true;
      }
      continue;
    }
    job = std::move(now);
  }
  if (as_json) {
    std::printf("%s\n", ProtoJson(job).c_str());
  } else if (!wait) {
    std::printf("solve job %s %s for session %s\n", job.id().c_str(),
                JobStateName(job.state()).c_str(), session.c_str());
  } else if (job.state() == pb::JOB_STATE_DONE) {
    std::printf("solved session %s: version %d, verdict %s, %s\n", session.c_str(), job.version(),
                job.verdict().c_str(),
                job.activated() ? "now active" : "candidate (not activated: see the report)");
  } else {
    std::printf("solve of session %s failed: %s\n", session.c_str(), job.error().c_str());
  }
  if (!wait) return kExitOk;
  if (job.state() == pb::JOB_STATE_FAILED) return kExitUndetermined;
  return ExitForVerdict(VerdictOf(job.verdict_kind(), job.verdict()));
}

int RunSolve(const std::vector<std::string>& argv) {
  auto a = ParseCommandFlags("solve", argv);
  if (!a.ok()) return UsageError(std::string(a.status().message()), kSolveHelp);
  if (a->Has("help")) return std::printf("%s%s", kSolveHelp, kServerFlagHelp), kExitOk;
  auto session = a->Get("session");
  if (!session || !a->positional().empty())
    return UsageError("solve needs --session S", kSolveHelp);
  auto seed = a->GetInt("seed", 0);
  auto timeout = a->GetDouble("timeout", 600);
  if (!seed.ok() || !timeout.ok())
    return UsageError("--seed and --timeout take numbers", kSolveHelp);
  Server server = Connect(*a);
  return SolveAndMaybeWait(server, *session, static_cast<uint64_t>(*seed), a->Has("wait"), *timeout,
                           a->Has("json"), a->Has("force"));
}

}  // namespace imucal::cli
