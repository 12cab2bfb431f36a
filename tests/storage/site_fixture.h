// A whole imucal site in a SQLite file, made through storage::Store and TokenStore as the
// server makes it, for the tests of copying a site to PostgreSQL (storage/copy.h,
// `imucald migrate`); and every table's rows read back with plain SELECTs, for comparing two
// databases value for value.
#ifndef IMUCAL_TESTS_STORAGE_SITE_FIXTURE_H_
#define IMUCAL_TESTS_STORAGE_SITE_FIXTURE_H_

#include <cstdint>
#include <cstring>
#include <limits>
#include <map>
#include <memory>
#include <optional>
#include <ostream>
#include <set>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/time/time.h"
#include "gtest/gtest.h"
#include "storage/sample_codec.h"
#include "storage/store.h"
#include "storage/tokens.h"
#include "tests/storage/test_util.h"
#include "util/db.h"

namespace imucal::storage {

// ---- Dumping tables ----------------------------------------------------------------------------

// One value as read: its kind ('N' NULL, 'I' integer, 'R' real as its IEEE bits, 'T' text,
// 'B' blob) and its bytes, so that two values compare equal only when they are the same bits.
struct DumpValue {
  char kind = 'N';
  std::string bytes;
  bool operator==(const DumpValue&) const = default;
};
using DumpRow = std::vector<DumpValue>;
using TableDump = std::vector<DumpRow>;

inline std::ostream& operator<<(std::ostream& os, const DumpValue& v) {
  os << v.kind << ':';
  if (v.kind == 'I' || v.kind == 'R') {
    uint64_t bits = 0;
    std::memcpy(&bits, v.bytes.data(), sizeof bits);
    if (v.kind == 'I') return os << static_cast<int64_t>(bits);
    double d;
    std::memcpy(&d, &bits, sizeof d);
    return os << d;
  }
  return os << v.bytes.substr(0, 40) << (v.bytes.size() > 40 ? "..." : "");
}

// The tables as this test knows them (written apart from storage/copy.cc on purpose): each
// column and its type letter, key first; SELECT every column in key order.
struct DumpTableSpec {
  const char* name;
  std::vector<std::pair<const char*, char>> columns;
  const char* select;
};

inline const std::vector<DumpTableSpec>& DumpSpecs() {
  static const std::vector<DumpTableSpec> specs = {
      {"devices",
       {{"id", 'T'},
        {"sensor_model", 'T'},
        {"nominal_rate_hz", 'R'},
        {"accel_unit", 'T'},
        {"gyro_unit", 'T'},
        {"created_at_us", 'I'}},
       "SELECT id, sensor_model, nominal_rate_hz, accel_unit, gyro_unit, created_at_us "
       "FROM devices ORDER BY id"},
      {"sessions",
       {{"rowid", 'I'},
        {"id", 'T'},
        {"device_id", 'T'},
        {"state", 'T'},
        {"protocol", 'T'},
        {"gravity_m_s2", 'R'},
        {"created_at_us", 'I'},
        {"updated_at_us", 'I'},
        {"source", 'T'}},
       "SELECT rowid, id, device_id, state, protocol, gravity_m_s2, created_at_us, "
       "updated_at_us, source FROM sessions ORDER BY rowid"},
      {"sample_batches",
       {{"session_id", 'T'},
        {"seq", 'I'},
        {"first_t_s", 'R'},
        {"last_t_s", 'R'},
        {"count", 'I'},
        {"end_sample", 'I'},
        {"payload", 'B'}},
       "SELECT session_id, seq, first_t_s, last_t_s, count, end_sample, payload "
       "FROM sample_batches ORDER BY session_id, seq"},
      {"poses",
       {{"session_id", 'T'},
        {"pose_index", 'I'},
        {"t_start_s", 'R'},
        {"t_end_s", 'R'},
        {"used", 'I'},
        {"reason", 'T'},
        {"detail_json", 'T'},
        {"face", 'T'}},
       "SELECT session_id, pose_index, t_start_s, t_end_s, used, reason, detail_json, face "
       "FROM poses ORDER BY session_id, pose_index"},
      {"pose_pairs",
       {{"session_id", 'T'},
        {"pose_a", 'I'},
        {"pose_b", 'I'},
        {"ok", 'I'},
        {"face", 'T'},
        {"rotation_deg", 'R'},
        {"tilt_deg", 'R'},
        {"reason", 'T'}},
       "SELECT session_id, pose_a, pose_b, ok, face, rotation_deg, tilt_deg, reason "
       "FROM pose_pairs ORDER BY session_id, pose_a, pose_b"},
      {"solves",
       {{"id", 'I'},
        {"session_id", 'T'},
        {"state", 'T'},
        {"actor", 'T'},
        {"started_at_us", 'I'},
        {"finished_at_us", 'I'},
        {"version", 'I'},
        {"error", 'T'},
        {"report_json", 'T'},
        {"owner", 'T'},
        {"lease_until_us", 'I'},
        {"seed", 'I'},
        {"attempts", 'I'}},
       "SELECT id, session_id, state, actor, started_at_us, finished_at_us, version, error, "
       "report_json, owner, lease_until_us, seed, attempts FROM solves ORDER BY id"},
      {"param_versions",
       {{"device_id", 'T'},
        {"version", 'I'},
        {"created_at_us", 'I'},
        {"session_id", 'T'},
        {"verdict", 'T'},
        {"accel_rms", 'R'},
        {"state", 'T'},
        {"provenance", 'T'},
        {"params_json", 'T'},
        {"report_json", 'T'}},
       "SELECT device_id, version, created_at_us, session_id, verdict, accel_rms, state, "
       "provenance, params_json, report_json FROM param_versions ORDER BY device_id, version"},
      {"audit_log",
       {{"id", 'I'},
        {"time_us", 'I'},
        {"actor", 'T'},
        {"action", 'T'},
        {"target", 'T'},
        {"detail", 'T'}},
       "SELECT id, time_us, actor, action, target, detail FROM audit_log ORDER BY id"},
      {"tokens",
       {{"id", 'I'},
        {"secret_sha256", 'B'},
        {"role", 'T'},
        {"device_id", 'T'},
        {"label", 'T'},
        {"created_at_us", 'I'},
        {"revoked_at_us", 'I'}},
       "SELECT id, secret_sha256, role, device_id, label, created_at_us, revoked_at_us "
       "FROM tokens ORDER BY id"},
  };
  return specs;
}

inline DumpValue ReadValue(const sql::Statement& st, int column, char type) {
  DumpValue v;
  if (st.ColumnIsNull(column)) return v;
  v.kind = type;
  if (type == 'I' || type == 'R') {
    uint64_t bits = 0;
    if (type == 'I') {
      const int64_t i = st.ColumnInt64(column);
      std::memcpy(&bits, &i, sizeof bits);
    } else {
      const double d = st.ColumnDouble(column);
      std::memcpy(&bits, &d, sizeof bits);
    }
    v.bytes.assign(reinterpret_cast<const char*>(&bits), sizeof bits);
  } else {
    v.bytes = st.ColumnBlob(column);
  }
  return v;
}

// Every table's rows, in key order, by table name.
inline absl::StatusOr<std::map<std::string, TableDump>> DumpTables(sql::Connection& conn) {
  std::map<std::string, TableDump> dump;
  for (const DumpTableSpec& spec : DumpSpecs()) {
    const auto map_row = [&spec](const sql::Statement& st) {
      DumpRow row;
      for (size_t i = 0; i < spec.columns.size(); ++i)
        row.push_back(ReadValue(st, static_cast<int>(i), spec.columns[i].second));
      return row;
    };
    absl::StatusOr<std::vector<DumpRow>> rows = sql::ReadRows(conn, spec.select, map_row);
    if (!rows.ok()) return rows.status();
    dump[spec.name] = *std::move(rows);
  }
  return dump;
}

// The columns each backend's schema has for `table` (SQLite's implicit rowid is not listed).
inline absl::StatusOr<std::set<std::string>> SchemaColumns(sql::Connection& conn,
                                                           const std::string& table) {
  const char* sql = conn.dialect() == sql::Dialect::kSqlite
                        ? "SELECT name FROM pragma_table_info(?1)"
                        : "SELECT CAST(column_name AS TEXT) FROM information_schema.columns "
                          "WHERE table_schema = current_schema() AND table_name = ?1";
  absl::StatusOr<std::vector<std::string>> names =
      sql::ReadRows(conn, sql, sql::FirstColumnText, table);
  if (!names.ok()) return names.status();
  return std::set<std::string>(names->begin(), names->end());
}

// ---- A site ------------------------------------------------------------------------------------

// Samples as a robot sends them, with values whose bits are easy to get wrong (subnormals,
// the largest double, 0.1 + 0.2, huge and tiny times); `temp`: with a temperature or without.
inline std::string SitePayload(int64_t seq, int samples, bool temp) {
  std::vector<ImuSample> out(static_cast<size_t>(samples));
  for (int i = 0; i < samples; ++i) {
    ImuSample& s = out[static_cast<size_t>(i)];
    s.t_s = 1000.0 * static_cast<double>(seq) + 0.005 * i + 0.1 + 0.2;
    s.accel = {0.01 * i + 1e-17, -9.80665 * (i % 2 == 0 ? 1 : -1), 5e-324 * i};
    s.gyro = {1e-3 * static_cast<double>(seq) / 3.0, std::numeric_limits<double>::max() * 0.5,
              -1e-300};
    if (temp) s.temp = 25.0 + 1.0 / (i + 3.0);
  }
  return EncodeSamples(out).value();
}

// What PopulateSite made, for the checks after a copy.
struct Site {
  std::vector<std::string> devices;
  std::vector<std::string> sessions;  // in creation order
  std::vector<std::string> token_secrets;
  int64_t revoked_token_id = 0;
};

// Every kind of row: devices; sessions open, solving (with a claimed, leased running solve),
// solved, failed and cancelled; batches of real encoded samples with and without temperature;
// poses and pairs; solves succeeded, failed and running; versions candidate, active, superseded
// and rejected, rolled back so that the active one is not the newest; tokens of each role (one
// revoked); audit rows of all of it, and one from outside storage.
inline absl::StatusOr<Site> PopulateSite(const std::string& path) {
  Site site;
  int64_t clock_us = 1700000000000000;  // a clock that moves 1.5 ms a call
  StoreOptions options;
  options.durability = Durability::kNormal;
  options.clock = [&clock_us] { return absl::FromUnixMicros(clock_us += 1500); };
  absl::StatusOr<std::unique_ptr<Store>> opened = Store::Open(path, options);
  if (!opened.ok()) return opened.status();
  Store& store = **opened;
#define SITE_OK(expr)                                  \
  do {                                                 \
    if (absl::Status s_ = (expr); !s_.ok()) return s_; \
  } while (false)
  for (const char* id : {"robot-1", "robot-2", "robot-3"}) {
    Device d = MakeDevice(id);
    d.nominal_rate_hz = 1000.0 / 3.0;
    d.sensor_model = "BMI088 \xc2\xb5-rev";  // UTF-8
    SITE_OK(store.CreateDevice(d, "admin:root").status());
    site.devices.push_back(id);
  }
  // Sessions are created in an order that is not their ids' order.
  const std::vector<std::pair<std::string, std::string>> sessions = {
      {"S-zeta", "robot-1"}, {"S-alpha", "robot-1"}, {"S-mid", "robot-2"},
      {"S-beta", "robot-2"}, {"S-open3", "robot-3"}, {"S-open1", "robot-1"}};
  for (const auto& [id, device] : sessions) {
    Session s = MakeSession(device, id);
    s.gravity_m_s2 = 9.80665 + 1e-9;
    absl::StatusOr<Session> created = store.CreateSession(s, "tech:alice");
    if (!created.ok()) return created.status();
    site.sessions.push_back(id);
    SITE_OK(store.SetSessionSource(id, "capture-" + id + ".csv"));
    for (int64_t seq = 1; seq <= 4; ++seq)
      SITE_OK(store
                  .AppendBatch(id, seq,
                               SitePayload(seq, 40 + 10 * static_cast<int>(seq),
                                           /*temp=*/seq % 2 == 1))
                  .status());
    std::vector<Pose> poses(3);
    for (int i = 0; i < 3; ++i) {
      poses[i].session_id = id;
      poses[i].index = i;
      poses[i].t_start_s = 1.0 / 3.0 + i;
      poses[i].t_end_s = 5e-324 + i + 2.5;
      poses[i].face = i == 0 ? "Z+" : "Z-";
      poses[i].detail_json = R"({"mean": [0.1, 0.2, 9.81], "temp_c": "25 \u00b0C"})";
    }
    poses[2].used = false;
    poses[2].reason = "moved during the hold (0.3\xc2\xb0)";
    std::vector<PosePair> pairs(1);
    pairs[0].session_id = id;
    pairs[0].pose_a = 1;
    pairs[0].pose_b = 2;
    pairs[0].ok = false;
    pairs[0].face = "Z-";
    pairs[0].rotation_deg = 179.29999999999998;
    pairs[0].tilt_deg = -0.0;
    pairs[0].reason = "turned 179.3 deg";
    SITE_OK(store.SavePoses(id, poses, pairs));
    // Only one open session per device: the others are moved on before the next is created.
    if (id == "S-zeta") {  // solved, version 1 active
      absl::StatusOr<Solve> solve = store.StartSolve(id, "server");
      if (!solve.ok()) return solve.status();
      ParamVersion v = MakeVersion("", Verdict::kPass, VersionState::kActive);
      SITE_OK(store.FinishSolve(solve->id, v, "server").status());
    } else if (id == "S-alpha") {  // a failed solve, the session failed
      absl::StatusOr<Solve> solve = store.StartSolve(id, "server");
      if (!solve.ok()) return solve.status();
      SITE_OK(store.FailSolve(solve->id, "too few poses: 3 of 6", R"({"poses": 3})", "server")
                  .status());
    } else if (id == "S-mid") {  // cancelled
      SITE_OK(store.SetSessionState(id, SessionState::kCancelled, "tech:bob").status());
    } else if (id == "S-beta") {  // solving: a running solve, a seed of 64 bits, claimed by a
                                  // second server after the first one's lease lapsed
      SolveClaim first{.owner = "host-a/10.0.0.1:50051",
                       .lease_until = absl::FromUnixMicros(1700000000000000)};
      SITE_OK(store.StartSolve(id, "server", first, /*seed=*/0xFEDCBA9876543210ull).status());
      SolveClaim second{.owner = "host-b/10.0.0.2:50051",
                        .lease_until = absl::FromUnixMicros(1800000000000000)};
      absl::StatusOr<std::optional<Solve>> claimed =
          store.ClaimLapsedSolve(absl::FromUnixMicros(1700000000000001), second);
      if (!claimed.ok()) return claimed.status();
      if (!claimed->has_value()) return absl::InternalError("S-beta's solve was not claimed");
    }
  }
  // robot-1: v2 candidate, v3 active (supersedes v1), v4 rejected, v5 candidate with no
  // accel_rms (NULL) nor session; then back to v1: active v1, superseded v3.
  ParamVersion v2 = MakeVersion("robot-1");
  v2.session_id = "S-zeta";
  SITE_OK(store.AddVersion(v2, "server").status());
  SITE_OK(store.AddVersion(MakeVersion("robot-1", Verdict::kWarn, VersionState::kActive), "server")
              .status());
  SITE_OK(store.AddVersion(MakeVersion("robot-1", Verdict::kFail), "server").status());
  SITE_OK(store.Reject("robot-1", 4, "tech:alice", "fails the gates").status());
  ParamVersion v5 = MakeVersion("robot-1");
  v5.accel_rms = std::numeric_limits<double>::quiet_NaN();
  SITE_OK(store.AddVersion(v5, "server").status());
  SITE_OK(store.Rollback("robot-1", 1, "tech:alice", "v3 drifts").status());
  // robot-2: a candidate only (no active version); robot-3: one promoted.
  SITE_OK(store.AddVersion(MakeVersion("robot-2"), "server").status());
  SITE_OK(store.AddVersion(MakeVersion("robot-3"), "server").status());
  SITE_OK(store.Promote("robot-3", 1, "tech:bob", "checked by hand").status());
  AuditEntry fetched;
  fetched.actor = "robot:robot-1";
  fetched.action = "params.fetch";
  fetched.target = DeviceTarget("robot-1");
  fetched.detail = "version 1, \"quoted\", tab\tand newline\n";
  SITE_OK(store.AppendAudit(fetched).status());
  opened->reset();

  absl::StatusOr<std::unique_ptr<TokenStore>> tokens = TokenStore::Open(path);
  if (!tokens.ok()) return tokens.status();
  absl::StatusOr<std::optional<NewToken>> admin =
      (*tokens)->CreateFirstAdmin("first admin", "imucald");
  if (!admin.ok()) return admin.status();
  site.token_secrets.push_back((*admin)->secret);
  for (const auto& [role, device, label] : std::vector<std::tuple<Role, std::string, std::string>>{
           {Role::kTechnician, "", "line-3 laptop"},
           {Role::kRobot, "robot-1", "robot-1"},
           {Role::kRobot, "robot-2", "robot-2 (lost)"}}) {
    absl::StatusOr<NewToken> t = (*tokens)->Create(role, device, label, "admin:root");
    if (!t.ok()) return t.status();
    site.token_secrets.push_back(t->secret);
    site.revoked_token_id = t->token.id;
  }
  SITE_OK((*tokens)->Revoke(site.revoked_token_id, "admin:root").status());
#undef SITE_OK
  return site;
}

}  // namespace imucal::storage

#endif  // IMUCAL_TESTS_STORAGE_SITE_FIXTURE_H_
