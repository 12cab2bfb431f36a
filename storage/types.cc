#include "storage/types.h"

#include <array>
#include <utility>

#include "absl/status/status.h"
#include "absl/strings/cord.h"
#include "util/str_util.h"

namespace imucal::storage {
namespace {

// The stored names, indexed by enum value. They appear in CHECK constraints of the schema
// (migrations.cc): change both together, through a migration.
constexpr std::array<std::string_view, 5> kSessionStateNames = {"open", "solving", "solved",
                                                                "cancelled", "failed"};
constexpr std::array<std::string_view, 3> kSolveStateNames = {"running", "succeeded", "failed"};
constexpr std::array<std::string_view, 3> kVerdictNames = {"pass", "warn", "fail"};
constexpr std::array<std::string_view, 4> kVersionStateNames = {"candidate", "active", "superseded",
                                                                "rejected"};

template <typename Enum, size_t N>
absl::StatusOr<Enum> Parse(const std::array<std::string_view, N>& names, std::string_view name,
                           std::string_view what) {
  for (size_t i = 0; i < N; ++i) {
    if (names[i] == name) return static_cast<Enum>(i);
  }
  return absl::InvalidArgumentError(Cat("unknown ", what, " '", name, "'"));
}

}  // namespace

std::string_view SessionStateName(SessionState state) {
  return kSessionStateNames[static_cast<size_t>(state)];
}
std::string_view SolveStateName(SolveState state) {
  return kSolveStateNames[static_cast<size_t>(state)];
}
std::string_view VerdictName(Verdict verdict) {
  return kVerdictNames[static_cast<size_t>(verdict)];
}
std::string_view VersionStateName(VersionState state) {
  return kVersionStateNames[static_cast<size_t>(state)];
}

absl::StatusOr<SessionState> ParseSessionState(std::string_view name) {
  return Parse<SessionState>(kSessionStateNames, name, "session state");
}
absl::StatusOr<SolveState> ParseSolveState(std::string_view name) {
  return Parse<SolveState>(kSolveStateNames, name, "solve state");
}
absl::StatusOr<Verdict> ParseVerdict(std::string_view name) {
  return Parse<Verdict>(kVerdictNames, name, "verdict");
}
absl::StatusOr<VersionState> ParseVersionState(std::string_view name) {
  return Parse<VersionState>(kVersionStateNames, name, "version state");
}

std::string DeviceTarget(std::string_view device_id) { return Cat("device:", device_id); }
std::string SessionTarget(std::string_view session_id) { return Cat("session:", session_id); }

absl::Status WithOperation(std::string_view op, const absl::Status& s) {
  if (s.ok()) return s;
  absl::Status out(s.code(), Cat(op, ": ", s.message()));
  // Every payload of `s` (kDatabaseErrorPayload among them), then the operation's prefix.
  s.ForEachPayload(
      [&out](absl::string_view type, const absl::Cord& payload) { out.SetPayload(type, payload); });
  std::string prefix = Cat(op, ": ");
  if (auto inner = s.GetPayload(kOperationPayload); inner.has_value())
    prefix += std::string(*inner);
  out.SetPayload(kOperationPayload, absl::Cord(prefix));
  return out;
}

}  // namespace imucal::storage
