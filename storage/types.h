// Domain types of imucal's storage: what goes into and comes out of `Store` (store.h).
//
// Parameter sets and reports are opaque JSON text here ("imucal-params v1" and
// "imucal-report v1", ../shared/spec/report.md); storage indexes only the few columns the
// service queries (device, version, created_at, verdict, accel_rms, state).
#ifndef IMUCAL_STORAGE_TYPES_H_
#define IMUCAL_STORAGE_TYPES_H_

#include <cstdint>
#include <functional>
#include <limits>
#include <optional>
#include <string>
#include <string_view>

#include "absl/status/statusor.h"
#include "absl/time/time.h"

namespace imucal::storage {

// A robot's IMU. `id` is chosen by the fleet (e.g. "robot-0042"); units are the capture
// format's names ("m/s^2", "g", "counts"; "rad/s", "deg/s", "counts").
struct Device {
  std::string id;
  std::string sensor_model;
  double nominal_rate_hz = 0.0;
  std::string accel_unit;
  std::string gyro_unit;
  absl::Time created_at;   // set by the store
  int active_version = 0;  // read-only: the active parameter version, 0 when none
};

// A session's states and the transitions Store allows (anything else is FailedPrecondition):
//   open    -> solving | cancelled | failed
//   solving -> solved | failed | open   (open: the solve needs more poses)
//   solved  -> solving                  (re-solve from the stored raw data)
//   failed  -> solving                  (retry)
//   cancelled: final
// Only `open` accepts sample batches; a device has at most one open session.
enum class SessionState { kOpen, kSolving, kSolved, kCancelled, kFailed };

struct Session {
  std::string id;  // empty on CreateSession: the store generates one
  std::string device_id;
  SessionState state = SessionState::kOpen;
  std::string protocol;           // "six-face", "positions", "free", ... (opaque to storage)
  double gravity_m_s2 = 9.80665;  // local gravity, kept for re-solves
  absl::Time created_at;
  absl::Time updated_at;  // last state change

  // Read-only, derived from the stored rows:
  // the highest batch seq durably stored; batches are numbered 1, 2, 3, ... so 0 = none yet;
  int64_t last_acked_seq = 0;
  int64_t samples = 0;     // samples in the stored batches
  int poses_accepted = 0;  // poses with used = true (PutPoses)
  int version = 0;         // version created by the session's latest successful solve; 0 none
  // A name for the capture (a file, a robot's capture label), set while the session holds no
  // samples (SetSessionSource); "" when none was given.
  std::string source;
};

// One batch of raw samples as the robot sent it, in `sample_codec.h`'s binary form.
struct SampleBatch {
  std::string session_id;
  int64_t seq = 0;         // 1, 2, 3, ... per session
  double first_t_s = 0.0;  // t of the first sample (from the payload)
  double last_t_s = 0.0;   // t of the last sample
  int64_t count = 0;       // samples in the payload
  std::string payload;     // EncodeSamples() bytes
};

// A static pose found in a session: the server's online segmentation stores each one as it is
// judged (Store::SavePoses, by index); a whole list can also be replaced (Store::PutPoses).
struct Pose {
  std::string session_id;
  int index = 0;  // 0, 1, 2, ... in time order
  double t_start_s = 0.0;
  double t_end_s = 0.0;
  bool used = true;
  std::string reason;       // why it is unused, for a technician
  std::string detail_json;  // means, sample count, temperature...: opaque to storage
  std::string face;         // six-face label ("Z+") when on a face, else empty
};

// A six-face pair verdict: two placements of one face, the second turned 180 degrees about the
// vertical (core/protocol.h PairCheck), as the server's online check judged it.
struct PosePair {
  std::string session_id;
  int pose_a = 0;  // pose indexes (Pose::index)
  int pose_b = 0;
  bool ok = false;
  std::string face;           // "Z+"
  double rotation_deg = 0.0;  // gyro-measured turn between the placements
  double tilt_deg = 0.0;      // floor tilt (half the angle between the two up directions)
  std::string reason;         // why rejected, in a technician's words
};

// One attempt to solve a session (a session can be re-solved from its raw data later).
enum class SolveState { kRunning, kSucceeded, kFailed };

struct Solve {
  int64_t id = 0;
  std::string session_id;
  SolveState state = SolveState::kRunning;
  std::string actor;
  absl::Time started_at;
  std::optional<absl::Time> finished_at;
  int version = 0;          // the parameter version it created; 0 = none
  std::string error;        // why it failed
  std::string report_json;  // a failed solve's report; a successful one's is its version's
  std::string owner;        // the server running it (SolveClaim); empty: none said
  absl::Time lease_until;   // it is that server's until then (renewed while it runs)
  uint64_t seed = 1;        // the calibration's seed, as the request gave it (core::CalibrateOptions)
  int attempts = 1;         // servers that have started it: 1, plus one per ClaimLapsedSolve
};

// Who runs a solve and for how long it may go without saying so again (Store::StartSolve,
// RenewSolveLeases): a server sharing the database with others claims the solves it runs.
// Unclaimed (the default), a running solve is an orphan to any server that looks, as are the
// solves of databases older than claims.
struct SolveClaim {
  std::string owner;                              // e.g. "host/127.0.0.1:50051"
  absl::Time lease_until = absl::InfinitePast();  // the default: lapsed already
};

// The one open sample stream of a device across the servers sharing a database (Store
// "Stream claims"): who holds it, for which session, until when unless renewed.
struct StreamClaim {
  std::string device_id;
  std::string holder;  // a server's instance, e.g. "r1 s0123456789abcdef"
  std::string session_id;
  absl::Time lease_until = absl::InfinitePast();
};

enum class Verdict { kPass, kWarn, kFail };

// What a robot is told when a batch is stored (or found already stored).
struct BatchAck {
  int64_t last_acked_seq = 0;  // every batch up to this one is durably stored
  int64_t samples = 0;         // samples stored in the session so far
};

// Version policy: a solve creates a `candidate`; it becomes `active` when it passes the quality
// gates or a technician promotes it; the version it displaces becomes `superseded`. A technician
// may `reject` a candidate. Rollback makes any earlier version active again.
enum class VersionState { kCandidate, kActive, kSuperseded, kRejected };

// An immutable parameter set version; only `state` ever changes.
struct ParamVersion {
  std::string device_id;
  int version = 0;  // 1, 2, 3, ... per device, assigned by the store
  absl::Time created_at;
  std::string session_id;  // the session it was solved from; empty if none
  std::string params_json;
  std::string report_json;
  Verdict verdict = Verdict::kFail;
  double accel_rms = std::numeric_limits<double>::quiet_NaN();  // m/s^2; NaN = unknown
  VersionState state = VersionState::kCandidate;
  std::string provenance;  // software version, solver settings, inputs: opaque text
};

// Writes a new version's documents, which carry its number, once the store has assigned that
// number: AddVersion and FinishSolve call it inside the transaction that assigns it, so the
// number inside the documents is the row's whichever process (another server sharing the
// database) adds a version meanwhile. An error aborts the add; nothing is written.
using RenderVersion = std::function<absl::Status(int version, std::string* params_json,
                                                 std::string* report_json)>;

// Who did what. Targets name the object: "device:<id>" (devices and their versions) or
// "session:<id>" (sessions, poses, solves).
struct AuditEntry {
  int64_t id = 0;  // increasing; assigned by the store
  absl::Time time;
  std::string actor;
  std::string action;  // e.g. "version.promote"
  std::string target;
  std::string detail;
};

// Names as stored and shown: "open", "solving", ...; "running", ...; "pass", ...; "candidate", ...
std::string_view SessionStateName(SessionState state);
std::string_view SolveStateName(SolveState state);
std::string_view VerdictName(Verdict verdict);
std::string_view VersionStateName(VersionState state);
absl::StatusOr<SessionState> ParseSessionState(std::string_view name);
absl::StatusOr<SolveState> ParseSolveState(std::string_view name);
absl::StatusOr<Verdict> ParseVerdict(std::string_view name);
absl::StatusOr<VersionState> ParseVersionState(std::string_view name);

// Audit targets.
std::string DeviceTarget(std::string_view device_id);
std::string SessionTarget(std::string_view session_id);

// Errors name the storage operation that failed first ("SetSessionState: session 's-1' is
// cancelled; ..."), for the server's log. That prefix (all of it, when operations nest) is
// also attached as this payload, so that the server's boundary can take it off: a client is
// told what is wrong, not which function found it.
inline constexpr char kOperationPayload[] = "imucal.storage/operation";
// `s` with "op: " in front of its message (and in the payload); OK stays OK.
absl::Status WithOperation(std::string_view op, const absl::Status& s);

}  // namespace imucal::storage

#endif  // IMUCAL_STORAGE_TYPES_H_
