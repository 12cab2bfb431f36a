// imucald's structured log: one line per event on stderr (journald and container runtimes
// collect it from there), as JSON or as logfmt text:
//
//   {"ts":"2024-05-01T12:00:00.123Z","level":"info","event":"rpc","method":"/imucal.v1...","code":"OK","duration_ms":0.42}
//   ts=2024-05-01T12:00:00.123Z level=info event=rpc method=/imucal.v1... code=OK duration_ms=0.42
//
// `ts` is UTC with milliseconds, `level` one of debug|info|warning|error, `event` a snake_case
// name (server_start, rpc, shutdown_begin, ...); the other keys are the event's fields. Each
// line is written with a single write(2), so lines from concurrent threads never interleave.
//
// RPCs are logged by a gRPC server interceptor (NewRpcLogInterceptorFactory): method, status
// code, duration and peer, for every call. Two kinds of call log their successes only at debug
// level: the robots' parameter fetch (GetActiveParameters, the hot path) and the orchestrators'
// health probes; above debug level they are not intercepted at all, so they pay nothing for the
// log (and their failures are then not logged either: the robot or the prober sees them).
#ifndef IMUCAL_SERVER_LOG_H_
#define IMUCAL_SERVER_LOG_H_

#include <cstdint>
#include <functional>
#include <initializer_list>
#include <memory>
#include <string>
#include <string_view>
#include <variant>

#include "absl/status/statusor.h"
#include "absl/strings/string_view.h"
#include "absl/time/time.h"
#include "grpcpp/support/server_interceptor.h"

namespace imucal::server {

enum class LogLevel { kDebug, kInfo, kWarning, kError };
enum class LogFormat { kJson, kText };

absl::StatusOr<LogLevel> ParseLogLevel(std::string_view name);    // "debug", "info", ...
absl::StatusOr<LogFormat> ParseLogFormat(std::string_view name);  // "json", "text"
std::string_view LogLevelName(LogLevel level);

struct LogOptions {
  LogLevel level = LogLevel::kInfo;
  LogFormat format = LogFormat::kJson;
};

// One key and its value; the value is printed as a JSON string, number or boolean.
class LogField {
 public:
  LogField(std::string_view key, std::string_view value) : key_(key), value_(value) {}
  LogField(std::string_view key, const char* value) : key_(key), value_(std::string_view(value)) {}
  LogField(std::string_view key, const std::string& value)
      : key_(key), value_(std::string_view(value)) {}
  LogField(std::string_view key, absl::string_view value)
      : key_(key), value_(std::string_view(value.data(), value.size())) {}
  LogField(std::string_view key, int value) : key_(key), value_(int64_t{value}) {}
  LogField(std::string_view key, int64_t value) : key_(key), value_(value) {}
  LogField(std::string_view key, uint64_t value) : key_(key), value_(static_cast<int64_t>(value)) {}
  LogField(std::string_view key, double value) : key_(key), value_(value) {}
  LogField(std::string_view key, bool value) : key_(key), value_(value) {}

  std::string_view key() const { return key_; }
  const std::variant<std::string_view, int64_t, double, bool>& value() const { return value_; }

 private:
  std::string_view key_;
  std::variant<std::string_view, int64_t, double, bool> value_;
};

// Process-wide: set once at start, before threads log. Lines go to `sink` (stderr when empty).
void ConfigureLog(const LogOptions& options,
                  std::function<void(std::string_view line)> sink = nullptr);
bool LogEnabled(LogLevel level);

// Writes one event line if `level` is enabled.
void Log(LogLevel level, std::string_view event, std::initializer_list<LogField> fields = {});

// The line Log writes (without calling the sink), for tests and the text of errors.
std::string FormatLogLine(LogFormat format, absl::Time ts, LogLevel level, std::string_view event,
                          std::initializer_list<LogField> fields);

// The fully qualified method whose successful calls log at debug level only (the hot path).
inline constexpr char kHotPathMethod[] = "/imucal.v1.ParameterService/GetActiveParameters";

// The canonical name of a gRPC status code ("NOT_FOUND"), as the RPC log writes it; "UNKNOWN"
// for a value outside the 17 codes.
std::string_view CodeName(grpc::StatusCode code);

// A server interceptor factory logging each RPC's completion as event "rpc": method, code,
// duration_ms, peer, and the status message when not OK. Non-OK calls log at info (warning
// for INTERNAL, UNKNOWN and DATA_LOSS), OK calls at info except the hot path and health
// checks (debug; see above).
std::unique_ptr<grpc::experimental::ServerInterceptorFactoryInterface>
NewRpcLogInterceptorFactory();

}  // namespace imucal::server

#endif  // IMUCAL_SERVER_LOG_H_
