// Column-mapped vendor CSV: a delimited text file whose columns the user names.
//
// The mapping (ColumnCsvOptions::map, the CLI's --columns) assigns the capture's fields to the
// file's columns, by header name or 1-based column number:
//   ax=acc_x,ay=acc_y,az=acc_z,gx=gyr_x,gy=gyr_y,gz=gyr_z[,t=time][,temp=temperature]
// Columns not named are ignored (they may hold text, e.g. a "part" label). Without gx, gy and gz
// (all three or none) the capture is accelerometer-only (core::Capture::has_gyro false).
//
// File layout: `skip_lines` preamble lines (default: everything before the first line that holds
// every mapped name, so a preamble needs no counting), a header line (unless `no_header`), then
// one row per sample. The delimiter is ',', ';' or tab, detected from the header line (or the
// first row) unless given; "space" splits on runs of spaces and tabs. Fields are split as RFC
// 4180 says (importers/csv_fields.h): "a,b" is one field, "" inside quotes a quote, a quoted line
// break joins the next line to the row. Blank lines are skipped; CRLF and a UTF-8 byte-order
// mark are accepted. A row that leaves a mapped column empty (an interleaved log of several
// sensors) is an error that suggests `skip_incomplete_rows`, which skips such rows and notes how
// many, and the first one's line.
//
// Time base, in seconds from the file's own origin:
//   t column, time_unit s|ms|us|ns  -> t_s = value * unit (the rate, if given, is only nominal);
//   t column, time_unit index       -> t_s = index / rate (a sample counter: a jump in the
//                                      counter stays a gap in time, it is not closed up);
//   no t column                     -> t_s = row / rate (row 0 at t = 0).
// The rate is `rate_hz`, or the number after the `rate_from_preamble` key in a preamble line
// ("Fs,100" with key "Fs"; "Fs=100" and "Fs: 100" also work).
// Time must increase strictly; with `sort_by_time` rows are put in time order instead (a file
// cut into labelled parts and saved part by part) and a note says how many were out of order;
// two rows with the same time are still an error. A note reports time gaps (an interval over
// 3x the median): the gyroscope was not recorded across a gap.
//
// Units: ImportOptions::accel_unit/gyro_unit (counts, g, m/s^2; counts, deg/s, rad/s), else
// inferred as for imu_tk (importers/unit_inference.h) with a note. Values are stored as read.
//
// Errors are InvalidArgument "SOURCE:LINE: column 'acc_x' (ax): 'abc' is not a number", or name
// the option at fault ("--columns: ...").
#ifndef IMUCAL_IMPORTERS_COLUMNS_H_
#define IMUCAL_IMPORTERS_COLUMNS_H_

#include <string>
#include <string_view>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "core/capture.h"
#include "importers/registry.h"

namespace imucal::importers {

// "s", "ms", "us", "ns", "index".
absl::StatusOr<ColumnTimeUnit> ParseColumnTimeUnit(std::string_view name);
std::string_view ColumnTimeUnitName(ColumnTimeUnit unit);

// Checks the options without reading a file (the CLI reports these as usage errors): the map
// names each of ax..gz exactly once, only known fields, and a rate when the time base needs one.
absl::Status CheckColumnCsvOptions(const ColumnCsvOptions& options);

// Parses `text` (the whole file); `source_name` prefixes error messages.
absl::StatusOr<core::Capture> ParseColumnCsv(std::string_view text, std::string_view source_name,
                                             const ImportOptions& options,
                                             std::vector<std::string>* notes);

// The "columns" importer for the registry (one file; never auto-detected from the content).
const CaptureImporter* ColumnCsvImporter();

}  // namespace imucal::importers

#endif  // IMUCAL_IMPORTERS_COLUMNS_H_
