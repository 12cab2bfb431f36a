// `imucal session`: open, list, show (with its poses and pair verdicts) or cancel calibration
// sessions (SessionService).
#include <cstdio>
#include <string>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_join.h"
#include "client/cli/args.h"
#include "client/cli/command_table.h"
#include "client/cli/commands.h"
#include "client/cli/server_common.h"

namespace imucal::cli {

namespace pb = imucal::v1;

namespace {

constexpr char kSessionHelp[] =
    "usage: imucal session start --device D [--protocol six-face|positions|free|ferraris|auto] "
    "[--json]\n"
    "       imucal session list [--device D] [--state open|solving|solved|failed|cancelled]\n"
    "       imucal session show ID [--json]\n"
    "       imucal session poses ID [--json]\n"
    "       imucal session cancel ID\n"
    "  Opens a calibration session (a device has at most one open), lists, shows (with its poses\n"
    "  and six-face pair verdicts as the server judged them while samples arrived), or cancels.\n"
    "options:\n"
    "  --gravity G       local gravity for `start`, m/s^2 (default 9.80665)\n";

void PrintSession(const pb::Session& s) {
  std::printf("%-14s %-18s %-9s %-9s %9lld samples %3d poses  %s%s\n", s.id().c_str(),
              s.device_id().c_str(), SessionStateName(s.state()).c_str(),
              ProtocolName(s.protocol()).c_str(), static_cast<long long>(s.samples()),
              s.poses_accepted(), TimeText(s.created_at()).c_str(),
              s.version() > 0 ? absl::StrCat("  -> v", s.version()).c_str() : "");
}

grpc::Status ListPoses(const Server& server, const std::string& session_id,
                       pb::ListPosesResponse* out) {
  pb::ListPosesRequest req;
  req.set_session_id(session_id);
  return server.sessions->ListPoses(CallContext().get(), req, out);
}

void PrintPoses(const pb::ListPosesResponse& poses) {
  for (const pb::PoseEvent& p : poses.poses()) {
    std::printf("  pose %2d %-3s %7.1f-%7.1f s  %s\n", p.index(), p.face().c_str(), p.t_start_s(),
                p.t_end_s(), p.accepted() ? "accepted" : ("rejected: " + p.reason()).c_str());
  }
  for (const pb::PairVerdict& p : poses.pairs()) {
    std::printf("  pair %-3s poses %d, %d: %s (turn %.1f deg, tilt %.1f deg)\n", p.face().c_str(),
                p.pose_a(), p.pose_b(), p.ok() ? "ok" : ("FAILED: " + p.reason()).c_str(),
                p.rotation_deg(), p.tilt_deg());
  }
}

absl::StatusOr<pb::SessionState> ParseState(const std::string& name) {
  for (int i = pb::SESSION_STATE_OPEN; i <= pb::SESSION_STATE_CANCELLED; ++i) {
    if (SessionStateName(static_cast<pb::SessionState>(i)) == name)
      return static_cast<pb::SessionState>(i);
  }
  return absl::InvalidArgumentError(absl::StrCat("--state: unknown state '", name, "'"));
}

// `session start`: opens a session for --device.
int StartSession(const Args& a, const Server& server, bool as_json) {
  auto device = a.Get("device");
  if (!device) return UsageError("session start needs --device", kSessionHelp);
  auto protocol = ParseProtocol(a.Get("protocol").value_or("auto"));
  if (!protocol.ok()) return UsageError(std::string(protocol.status().message()), kSessionHelp);
  auto gravity = a.GetDouble("gravity", 0.0);
  if (!gravity.ok()) return UsageError(std::string(gravity.status().message()), kSessionHelp);
  pb::Session s;
  if (grpc::Status st = CreateSession(server, *device, *protocol, *gravity, &s); !st.ok())
    return RpcError(server, st);
  if (as_json) return std::printf("%s\n", ProtoJson(s).c_str()), kExitOk;
  std::printf("session %s opened for %s (protocol %s)\n", s.id().c_str(), s.device_id().c_str(),
              ProtocolName(s.protocol()).c_str());
  return kExitOk;
}

// `session list`: every page of the sessions, filtered by --device and --state.
int ListSessions(const Args& a, const Server& server, bool as_json) {
  pb::ListSessionsResponse all;
  pb::ListSessionsRequest req;
  req.set_device_id(a.Get("device").value_or(""));
  if (auto st = a.Get("state")) {
    auto state = ParseState(*st);
    if (!state.ok()) return UsageError(std::string(state.status().message()), kSessionHelp);
    req.set_state(*state);
  }
  grpc::Status st = ForEachPage(server.sessions.get(), &pb::SessionService::Stub::ListSessions, req,
                                [&](pb::ListSessionsResponse& page) {
                                  for (auto& s : *page.mutable_sessions())
                                    *all.add_sessions() = std::move(s);
                                });
  if (!st.ok()) return RpcError(server, st);
  if (as_json) return std::printf("%s\n", ProtoJson(all).c_str()), kExitOk;
  if (all.sessions().empty()) std::printf("no sessions\n");
  for (const auto& s : all.sessions()) PrintSession(s);
  return kExitOk;
}

// `session poses ID`.
int ShowPoses(const Server& server, const std::string& session_id, bool as_json) {
  pb::ListPosesResponse poses;
  if (grpc::Status st = ListPoses(server, session_id, &poses); !st.ok())
    return RpcError(server, st);
  if (as_json) return std::printf("%s\n", ProtoJson(poses).c_str()), kExitOk;
  if (poses.poses().empty()) std::printf("no poses yet\n");
  PrintPoses(poses);
  return kExitOk;
}

// `session show ID` (the session and its poses) or `session cancel ID`.
int ShowOrCancel(const Server& server, const std::string& verb, const std::string& session_id,
                 bool as_json) {
  pb::Session s;
  grpc::Status st;
  if (verb == "show") {
    st = GetSession(server, session_id, &s);
  } else {
    pb::CancelSessionRequest req;
    req.set_session_id(session_id);
    st = server.sessions->CancelSession(CallContext().get(), req, &s);
  }
  if (!st.ok()) return RpcError(server, st);
  if (as_json) return std::printf("%s\n", ProtoJson(s).c_str()), kExitOk;
  if (verb == "cancel") std::printf("cancelled session %s\n", s.id().c_str());
  PrintSession(s);
  if (verb == "show") {
    pb::ListPosesResponse poses;
    if (grpc::Status ps = ListPoses(server, session_id, &poses); !ps.ok())
      return RpcError(server, ps);
    PrintPoses(poses);
  }
  return kExitOk;
}

}  // namespace

int RunSession(const std::vector<std::string>& argv) {
  auto a = ParseCommandFlags("session", argv);
  if (!a.ok()) return UsageError(std::string(a.status().message()), kSessionHelp);
  if (a->Has("help")) return std::printf("%s%s", kSessionHelp, kServerFlagHelp), kExitOk;
  const auto& pos = a->positional();
  if (pos.empty())
    return UsageError("session needs start, list, show, poses or cancel", kSessionHelp);
  Server server = Connect(*a);
  const bool as_json = a->Has("json");
  if (pos[0] == "start" && pos.size() == 1) return StartSession(*a, server, as_json);
  if (pos[0] == "list" && pos.size() == 1) return ListSessions(*a, server, as_json);
  if (pos[0] == "poses" && pos.size() == 2) return ShowPoses(server, pos[1], as_json);
  if ((pos[0] == "show" || pos[0] == "cancel") && pos.size() == 2)
    return ShowOrCancel(server, pos[0], pos[1], as_json);
  return UsageError(absl::StrCat("session: unexpected '", absl::StrJoin(pos, " "), "'"),
                    kSessionHelp);
}

}  // namespace imucal::cli
