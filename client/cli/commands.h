// The imucal CLI's commands. Each takes the arguments after its name and returns the exit code.
#ifndef IMUCAL_CLIENT_CLI_COMMANDS_H_
#define IMUCAL_CLIENT_CLI_COMMANDS_H_

#include <string>
#include <vector>

#include "absl/status/status.h"

namespace imucal::cli {

// Exit codes, stable for scripts.
inline constexpr int kExitOk = 0;           // done (verdict pass or warn)
inline constexpr int kExitUsage = 1;        // bad command line
inline constexpr int kExitBadInput = 2;     // unreadable or malformed input
inline constexpr int kExitUndetermined = 3; // the capture cannot determine the calibration
inline constexpr int kExitVerdictFail = 4;  // calibrated, but the result fails the quality gates
inline constexpr int kExitInternal = 5;

// Prints "imucal: <message>" to stderr and maps the status to an exit code.
int ReportError(const absl::Status& status);

int RunCalibrate(const std::vector<std::string>& args);
int RunApply(const std::vector<std::string>& args);
int RunSimulate(const std::vector<std::string>& args);
int RunDemo(const std::vector<std::string>& args);

}  // namespace imucal::cli

#endif  // IMUCAL_CLIENT_CLI_COMMANDS_H_
