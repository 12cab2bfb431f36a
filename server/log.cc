#include "server/log.h"

#include <unistd.h>

#include <array>
#include <atomic>
#include <charconv>
#include <cmath>
#include <cstring>

#include "absl/strings/string_view.h"
#include "grpcpp/server_context.h"
#include "util/str_util.h"

namespace imucal::server {
namespace {

struct LogState {
  std::atomic<int> level{static_cast<int>(LogLevel::kInfo)};
  LogFormat format = LogFormat::kJson;
  std::function<void(std::string_view)> sink;
};

LogState& State() {
  static LogState* state = new LogState();  // never destroyed: threads may log during exit
  return *state;
}

void WriteAll(int fd, std::string_view line) {
  while (!line.empty()) {
    const ssize_t n = ::write(fd, line.data(), line.size());
    if (n < 0) {
      if (errno == EINTR) continue;
      return;  // nowhere to report a failing stderr
    }
    line.remove_prefix(static_cast<size_t>(n));
  }
}

void AppendJsonString(std::string* out, std::string_view s) {
  out->push_back('"');
  for (const char c : s) {
    switch (c) {
      case '"':
        out->append("\\\"");
        break;
      case '\\':
        out->append("\\\\");
        break;
      case '\n':
        out->append("\\n");
        break;
      case '\r':
        out->append("\\r");
        break;
      case '\t':
        out->append("\\t");
        break;
      default:
        if (static_cast<unsigned char>(c) < 0x20) {
          static constexpr char kHex[] = "0123456789abcdef";
          out->append("\\u00");
          out->push_back(kHex[(c >> 4) & 0xf]);
          out->push_back(kHex[c & 0xf]);
        } else {
          out->push_back(c);
        }
    }
  }
  out->push_back('"');
}

// logfmt: bare when the value has no space, quote, '=' or control character; else quoted with
// JSON escapes (what logfmt parsers accept).
void AppendTextValue(std::string* out, std::string_view s) {
  bool bare = !s.empty();
  for (const char c : s) {
    if (c == ' ' || c == '"' || c == '=' || c == '\\' || static_cast<unsigned char>(c) < 0x20) {
      bare = false;
      break;
    }
  }
  if (bare) {
    out->append(s);
  } else {
    AppendJsonString(out, s);
  }
}

void AppendNumber(std::string* out, double value) {
  if (!std::isfinite(value)) {  // JSON has no NaN/inf: print them as strings
    AppendJsonString(out, std::isnan(value) ? "nan" : (value > 0 ? "inf" : "-inf"));
    return;
  }
  std::array<char, 32> buffer;
  // Three decimals: durations in ms to the microsecond; the shortest form otherwise.
  const double rounded = std::round(value * 1000.0) / 1000.0;
  const auto result = std::to_chars(buffer.data(), buffer.data() + buffer.size(), rounded);
  out->append(buffer.data(), result.ptr);
}

void AppendValue(std::string* out, LogFormat format, const LogField& field) {
  const auto& v = field.value();
  if (const auto* s = std::get_if<std::string_view>(&v)) {
    if (format == LogFormat::kJson) {
      AppendJsonString(out, *s);
    } else {
      AppendTextValue(out, *s);
    }
  } else if (const auto* i = std::get_if<int64_t>(&v)) {
    AppendPiece(out, *i);
  } else if (const auto* d = std::get_if<double>(&v)) {
    AppendNumber(out, *d);
  } else {
    out->append(std::get<bool>(v) ? "true" : "false");
  }
}

}  // namespace

absl::StatusOr<LogLevel> ParseLogLevel(std::string_view name) {
  if (name == "debug") return LogLevel::kDebug;
  if (name == "info") return LogLevel::kInfo;
  if (name == "warning" || name == "warn") return LogLevel::kWarning;
  if (name == "error") return LogLevel::kError;
  return absl::InvalidArgumentError(
      Cat("expected debug, info, warning or error, got '", name, "'"));
}

absl::StatusOr<LogFormat> ParseLogFormat(std::string_view name) {
  if (name == "json") return LogFormat::kJson;
  if (name == "text") return LogFormat::kText;
  return absl::InvalidArgumentError(Cat("expected json or text, got '", name, "'"));
}

std::string_view LogLevelName(LogLevel level) {
  switch (level) {
    case LogLevel::kDebug:
      return "debug";
    case LogLevel::kInfo:
      return "info";
    case LogLevel::kWarning:
      return "warning";
    case LogLevel::kError:
      return "error";
  }
  return "info";
}

void ConfigureLog(const LogOptions& options, std::function<void(std::string_view line)> sink) {
  LogState& state = State();
  state.format = options.format;
  state.sink = std::move(sink);
  state.level.store(static_cast<int>(options.level), std::memory_order_relaxed);
}

bool LogEnabled(LogLevel level) {
  return static_cast<int>(level) >= State().level.load(std::memory_order_relaxed);
}

std::string FormatLogLine(LogFormat format, absl::Time ts, LogLevel level, std::string_view event,
                          std::initializer_list<LogField> fields) {
  const std::string time = absl::FormatTime("%Y-%m-%dT%H:%M:%E3SZ", ts, absl::UTCTimeZone());
  std::string line;
  line.reserve(96 + 32 * fields.size());
  if (format == LogFormat::kJson) {
    AppendTo(&line, "{\"ts\":\"", time, "\",\"level\":\"", LogLevelName(level), "\",\"event\":");
    AppendJsonString(&line, event);
    for (const LogField& field : fields) {
      line.push_back(',');
      AppendJsonString(&line, field.key());
      line.push_back(':');
      AppendValue(&line, format, field);
    }
    line.append("}\n");
  } else {
    AppendTo(&line, "ts=", time, " level=", LogLevelName(level), " event=");
    AppendTextValue(&line, event);
    for (const LogField& field : fields) {
      AppendTo(&line, " ", field.key(), "=");
      AppendValue(&line, format, field);
    }
    line.push_back('\n');
  }
  return line;
}

void Log(LogLevel level, std::string_view event, std::initializer_list<LogField> fields) {
  if (!LogEnabled(level)) return;
  const LogState& state = State();
  const std::string line = FormatLogLine(state.format, absl::Now(), level, event, fields);
  if (state.sink) {
    state.sink(line);
  } else {
    WriteAll(STDERR_FILENO, line);
  }
}

std::string_view CodeName(grpc::StatusCode code) {
  static constexpr std::array<std::string_view, 17> kNames = {"OK",
                                                              "CANCELLED",
                                                              "UNKNOWN",
                                                              "INVALID_ARGUMENT",
                                                              "DEADLINE_EXCEEDED",
                                                              "NOT_FOUND",
                                                              "ALREADY_EXISTS",
                                                              "PERMISSION_DENIED",
                                                              "RESOURCE_EXHAUSTED",
                                                              "FAILED_PRECONDITION",
                                                              "ABORTED",
                                                              "OUT_OF_RANGE",
                                                              "UNIMPLEMENTED",
                                                              "INTERNAL",
                                                              "UNAVAILABLE",
                                                              "DATA_LOSS",
                                                              "UNAUTHENTICATED"};
  const int i = static_cast<int>(code);
  return i >= 0 && i < static_cast<int>(kNames.size()) ? kNames[i] : "UNKNOWN";
}

namespace {

// Probed every few seconds by orchestrators: their successes are noise at info level.
constexpr char kHealthMethods[] = "/grpc.health.v1.Health/";

LogLevel LevelOf(grpc::StatusCode code, bool quiet) {
  switch (code) {
    case grpc::StatusCode::OK:
      return quiet ? LogLevel::kDebug : LogLevel::kInfo;
    case grpc::StatusCode::INTERNAL:
    case grpc::StatusCode::UNKNOWN:
    case grpc::StatusCode::DATA_LOSS:
      return LogLevel::kWarning;
    default:
      return LogLevel::kInfo;
  }
}

// One per call. The status is known at PRE_SEND_STATUS; the line is written then (for streams
// too: their status is the end of the call).
class RpcLogInterceptor final : public grpc::experimental::Interceptor {
 public:
  RpcLogInterceptor(grpc::experimental::ServerRpcInfo* info, bool quiet)
      : info_(info), quiet_(quiet), start_(absl::Now()) {}

  void Intercept(grpc::experimental::InterceptorBatchMethods* methods) override {
    if (methods->QueryInterceptionHookPoint(
            grpc::experimental::InterceptionHookPoints::PRE_SEND_STATUS)) {
      LogCompletion(methods->GetSendStatus());
    }
    methods->Proceed();
  }

 private:
  void LogCompletion(const grpc::Status& status) const {
    const LogLevel level = LevelOf(status.error_code(), quiet_);
    if (!LogEnabled(level)) return;
    const double duration_ms = absl::ToDoubleMilliseconds(absl::Now() - start_);
    const std::string peer = info_->server_context()->peer();
    const std::string_view method = info_->method();
    const std::string_view code = CodeName(status.error_code());
    if (status.ok()) {
      Log(level, "rpc",
          {{"method", method}, {"code", code}, {"duration_ms", duration_ms}, {"peer", peer}});
    } else {
      Log(level, "rpc",
          {{"method", method},
           {"code", code},
           {"duration_ms", duration_ms},
           {"peer", peer},
           {"message", status.error_message()}});
    }
  }

  grpc::experimental::ServerRpcInfo* info_;
  bool quiet_;  // a hot-path or health method: successes at debug level
  absl::Time start_;
};

class RpcLogInterceptorFactory final
    : public grpc::experimental::ServerInterceptorFactoryInterface {
 public:
  grpc::experimental::Interceptor* CreateServerInterceptor(
      grpc::experimental::ServerRpcInfo* info) override {
    const char* method = info->method();
    const bool quiet = method != nullptr &&
                       (std::strcmp(method, kHotPathMethod) == 0 ||
                        std::strncmp(method, kHealthMethods, sizeof(kHealthMethods) - 1) == 0);
    // Quiet methods are not intercepted unless their successes would be logged: no
    // allocation, no hook, nothing on the robots' fetch (bench/fetch_bench measures it).
    if (quiet && !LogEnabled(LogLevel::kDebug)) return nullptr;
    return new RpcLogInterceptor(info, quiet);
  }
};

}  // namespace

std::unique_ptr<grpc::experimental::ServerInterceptorFactoryInterface>
NewRpcLogInterceptorFactory() {
  return std::make_unique<RpcLogInterceptorFactory>();
}

}  // namespace imucal::server
