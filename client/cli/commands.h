// The imucal CLI's commands. Each takes the arguments after its name and returns the exit code.
#ifndef IMUCAL_CLIENT_CLI_COMMANDS_H_
#define IMUCAL_CLIENT_CLI_COMMANDS_H_

#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "absl/status/status.h"
#include "core/calibrate/verdict.h"

namespace imucal::cli {

// Exit codes, stable for scripts.
inline constexpr int kExitOk = 0;            // done (verdict pass or warn)
inline constexpr int kExitUsage = 1;         // bad command line
inline constexpr int kExitBadInput = 2;      // unreadable or malformed input
inline constexpr int kExitUndetermined = 3;  // the capture cannot determine the calibration
inline constexpr int kExitVerdictFail = 4;   // calibrated, but the result fails the quality gates
inline constexpr int kExitInternal = 5;
inline constexpr int kExitUnavailable = 6;  // the server could not be reached (or timed out)
inline constexpr int kExitDenied = 7;       // the server refused the token or the role

// The exit code of a finished calibration by its verdict: kExitVerdictFail for "fail" (and for
// none this client knows: it cannot vouch for it), else kExitOk.
inline int ExitForVerdict(std::optional<core::Verdict> verdict) {
  if (verdict == core::Verdict::kRefused) return kExitUndetermined;  // a report, no parameters
  return verdict.value_or(core::Verdict::kFail) == core::Verdict::kFail ? kExitVerdictFail
                                                                        : kExitOk;
}

// Prints "imucal: <message>" to stderr and maps the status to an exit code.
int ReportError(const absl::Status& status);

int RunCalibrate(const std::vector<std::string>& args);
int RunApply(const std::vector<std::string>& args);
int RunSimulate(const std::vector<std::string>& args);
int RunDemo(const std::vector<std::string>& args);
// `imucal noise REST...` or `imucal noise --session S`: noise figures from a rest recording
// alone (noise_command.cc), read from files or from the server (noise_session.cc, in the server
// commands' library).
int RunNoise(const std::vector<std::string>& args);
// `imucal learn`: the gyro's dynamic block from recordings with a reference (learn_command.cc).
int RunLearn(const std::vector<std::string>& args);
// `imucal export --params FILE --format F`: a parameter set file as json, Kalibr or OpenVINS
// YAML (core/export.h). main.cc sends `export` here unless it names a --device (the server's).
int RunExportFile(const std::vector<std::string>& args);
// The main job through the service: guide + simulated robot + solve + SDK fetch and apply.
int RunServerDemo(const std::vector<std::string>& args);

// Server commands (device_commands.cc, session_commands.cc, upload_command.cc, solve_command.cc,
// report_command.cc, params_commands.cc, export_command.cc, guide.cc). Each accepts --server ADDR
// (else $IMUCAL_SERVER, else 127.0.0.1:50051). A server error prints the server's message; the exit
// code is kExitUnavailable when the server is unreachable, kExitBadInput for an invalid
// argument or an unknown id, kExitUndetermined for a state that forbids the call.
int RunDevices(const std::vector<std::string>& args);
int RunSession(const std::vector<std::string>& args);
int RunUpload(const std::vector<std::string>& args);
int RunSolve(const std::vector<std::string>& args);
int RunReport(const std::vector<std::string>& args);
int RunParams(const std::vector<std::string>& args);
int RunExport(const std::vector<std::string>& args);
int RunGuide(const std::vector<std::string>& args);
// `imucal admin token create|list|revoke` (admin_commands.cc).
int RunAdmin(const std::vector<std::string>& args);

// Takes the connection flags --token T, --token-file F and --ca-cert PEM out of `argv`
// wherever they stand (falling back to $IMUCAL_TOKEN, $IMUCAL_TOKEN_FILE, $IMUCAL_CA_CERT),
// reads the files, and keeps the result for every server command's Connect()
// (server_common.cc). InvalidArgument naming the flag or variable for a missing value, an
// unreadable file, or a token without a CA certificate (a token is sent only over TLS).
absl::Status TakeConnectionFlags(std::vector<std::string>* argv);

}  // namespace imucal::cli

#endif  // IMUCAL_CLIENT_CLI_COMMANDS_H_
