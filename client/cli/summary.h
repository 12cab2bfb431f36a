// The human-readable calibration summary printed by `imucal calibrate`.
#ifndef IMUCAL_CLIENT_CLI_SUMMARY_H_
#define IMUCAL_CLIENT_CLI_SUMMARY_H_

#include <string>

#include "core/calibrate.h"

namespace imucal::cli {

std::string FormatSummary(const core::CalibrationReport& report);

}  // namespace imucal::cli

#endif  // IMUCAL_CLIENT_CLI_SUMMARY_H_
