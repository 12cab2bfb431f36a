// `imucal admin token create|list|revoke`: API tokens through AdminService (admin role).
#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <string>
#include <vector>

#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "client/cli/args.h"
#include "client/cli/command_table.h"
#include "client/cli/commands.h"
#include "client/cli/server_common.h"

namespace imucal::cli {
namespace pb = ::imucal::v1;
namespace {

constexpr char kAdminHelp[] =
    "usage: imucal admin token create --role robot|technician|admin [--device D] [--label L]\n"
    "                                 [--out FILE] [--json]\n"
    "       imucal admin token list [--all] [--json]\n"
    "       imucal admin token revoke ID [--json]\n"
    "API tokens; the caller's token must have the admin role.\n"
    "  create   a new token; a robot token is bound to one device (--device). The secret is\n"
    "           printed once (or, with --out FILE, written to FILE with mode 0600 instead):\n"
    "           store it now, the server keeps only its SHA-256\n"
    "  list     the valid tokens (--all: revoked ones too), without secrets\n"
    "  revoke   ID (from list): calls with the token fail from now on\n"
    "  --json   the response as JSON (.proto field names)\n"
    "  --server ADDR, --ca-cert PEM, --token-file F | --token T: see imucal --help\n"
    "exit codes: 0 ok, 1 usage, 2 bad input or unknown id, 5 internal, 6 server unreachable,\n"
    "            7 the server refused the token or its role\n";

absl::StatusOr<pb::Role> ParseRole(const std::string& name) {
  if (name == "robot") return pb::ROLE_ROBOT;
  if (name == "technician") return pb::ROLE_TECHNICIAN;
  if (name == "admin") return pb::ROLE_ADMIN;
  return absl::InvalidArgumentError(
      absl::StrCat("--role: '", name, "' is not robot, technician or admin"));
}

std::string RoleWord(pb::Role role) {
  switch (role) {
    case pb::ROLE_ROBOT:
      return "robot";
    case pb::ROLE_TECHNICIAN:
      return "technician";
    case pb::ROLE_ADMIN:
      return "admin";
    default:
      return "unknown";
  }
}

// "robot for device D" / "technician", and the label.
std::string Describe(const pb::Token& t) {
  std::string out = RoleWord(t.role());
  if (!t.device_id().empty()) absl::StrAppend(&out, " for device ", t.device_id());
  if (!t.label().empty()) absl::StrAppend(&out, ", label \"", t.label(), "\"");
  return out;
}

// The secret alone on one line, readable by its owner only (an existing file is replaced).
absl::Status WriteSecret(const std::string& path, const std::string& secret) {
  const int fd = ::open(path.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_NOFOLLOW | O_CLOEXEC, 0600);
  if (fd < 0)
    return absl::InvalidArgumentError(
        absl::StrCat("--out: cannot write ", path, ": ", std::strerror(errno)));
  const std::string line = secret + "\n";
  const bool ok = ::fchmod(fd, 0600) == 0 &&
                  ::write(fd, line.data(), line.size()) == static_cast<ssize_t>(line.size());
  const int err = errno;
  ::close(fd);
  if (!ok)
    return absl::InvalidArgumentError(
        absl::StrCat("--out: cannot write ", path, ": ", std::strerror(err)));
  return absl::OkStatus();
}

int Create(const Server& server, const Args& a) {
  if (a.positional().size() != 2) return UsageError("token create takes no ID", kAdminHelp);
  if (!a.Get("role")) return UsageError("token create needs --role", kAdminHelp);
  absl::StatusOr<pb::Role> role = ParseRole(*a.Get("role"));
  if (!role.ok()) return UsageError(std::string(role.status().message()), kAdminHelp);
  if (*role == pb::ROLE_ROBOT && !a.Get("device"))
    return UsageError("--device: a robot token is bound to one device", kAdminHelp);
  if (*role != pb::ROLE_ROBOT && a.Get("device"))
    return UsageError("--device: only robot tokens are bound to a device", kAdminHelp);
  pb::CreateTokenRequest req;
  req.set_role(*role);
  req.set_device_id(a.Get("device").value_or(""));
  req.set_label(a.Get("label").value_or(""));
  pb::CreateTokenResponse created;
  if (grpc::Status s = server.admin->CreateToken(CallContext().get(), req, &created); !s.ok())
    return RpcError(server, s);
  const std::optional<std::string> out = a.Get("out");
  if (out) {
    if (absl::Status s = WriteSecret(*out, created.secret()); !s.ok()) {
      // The token exists but nobody has its secret: revoke it rather than leave it behind.
      pb::RevokeTokenRequest revoke;
      revoke.set_id(created.token().id());
      pb::Token ignored;
      (void)server.admin->RevokeToken(CallContext().get(), revoke, &ignored);
      return ReportError(absl::Status(
          s.code(),
          absl::StrCat(s.message(), " (token ", created.token().id(), " was revoked again)")));
    }
    created.clear_secret();
  }
  if (a.Has("json")) return std::printf("%s\n", ProtoJson(created).c_str()), kExitOk;
  std::printf("token %lld created: %s\n", static_cast<long long>(created.token().id()),
              Describe(created.token()).c_str());
  if (out) {
    std::printf("secret written to %s (mode 0600)\n", out->c_str());
  } else {
    std::printf("secret (shown once; store it now):\n%s\n", created.secret().c_str());
  }
  return kExitOk;
}

int List(const Server& server, const Args& a) {
  if (a.positional().size() != 2) return UsageError("token list takes no ID", kAdminHelp);
  pb::ListTokensRequest req;
  req.set_include_revoked(a.Has("all"));
  pb::ListTokensResponse tokens;
  if (grpc::Status s = server.admin->ListTokens(CallContext().get(), req, &tokens); !s.ok())
    return RpcError(server, s);
  if (a.Has("json")) return std::printf("%s\n", ProtoJson(tokens).c_str()), kExitOk;
  if (tokens.tokens().empty()) return std::printf("no tokens\n"), kExitOk;
  std::printf("%-5s %-11s %-20s %-28s %-28s %s\n", "ID", "ROLE", "DEVICE", "CREATED", "REVOKED",
              "LABEL");
  for (const pb::Token& t : tokens.tokens()) {
    std::printf("%-5lld %-11s %-20s %-28s %-28s %s\n", static_cast<long long>(t.id()),
                RoleWord(t.role()).c_str(), t.device_id().empty() ? "-" : t.device_id().c_str(),
                TimeText(t.created_at()).c_str(), TimeText(t.revoked_at()).c_str(),
                t.label().empty() ? "-" : t.label().c_str());
  }
  return kExitOk;
}

int Revoke(const Server& server, const Args& a) {
  int64_t id = 0;
  if (a.positional().size() != 3 || !absl::SimpleAtoi(a.positional()[2], &id) || id < 1)
    return UsageError("token revoke needs the token's ID (a number, from token list)", kAdminHelp);
  pb::RevokeTokenRequest req;
  req.set_id(id);
  pb::Token revoked;
  if (grpc::Status s = server.admin->RevokeToken(CallContext().get(), req, &revoked); !s.ok())
    return RpcError(server, s);
  if (a.Has("json")) return std::printf("%s\n", ProtoJson(revoked).c_str()), kExitOk;
  std::printf("token %lld revoked (%s), at %s\n", static_cast<long long>(revoked.id()),
              Describe(revoked).c_str(), TimeText(revoked.revoked_at()).c_str());
  return kExitOk;
}

}  // namespace

int RunAdmin(const std::vector<std::string>& argv) {
  auto a = ParseCommandFlags("admin", argv);
  if (!a.ok()) return UsageError(std::string(a.status().message()), kAdminHelp);
  if (a->Has("help")) return std::printf("%s", kAdminHelp), kExitOk;
  const std::vector<std::string>& pos = a->positional();
  if (pos.size() < 2 || pos[0] != "token")
    return UsageError("expected admin token create|list|revoke", kAdminHelp);
  Server server = Connect(*a);
  if (pos[1] == "create") return Create(server, *a);
  if (pos[1] == "list") return List(server, *a);
  if (pos[1] == "revoke") return Revoke(server, *a);
  return UsageError(absl::StrCat("unknown admin token command '", pos[1], "'"), kAdminHelp);
}

}  // namespace imucal::cli
