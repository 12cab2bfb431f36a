// The calibration report as JSON: "imucal-report v1" of ../shared/spec/report.md.
#ifndef IMUCAL_FORMATS_REPORT_JSON_H_
#define IMUCAL_FORMATS_REPORT_JSON_H_

#include <string>

#include "core/calibrate/calibrate.h"

namespace imucal::formats {

// Pretty-printed (2 spaces). Non-finite numbers are written as null.
std::string ReportToJson(const core::CalibrationReport& report);

}  // namespace imucal::formats

#endif  // IMUCAL_FORMATS_REPORT_JSON_H_
