// The imucal capture CSV, version 1 (../shared/spec/capture-format.md): imucal's own capture
// file, read ("imucal" importer) and written (`imucal export`, `imucal simulate`, tests).
#ifndef IMUCAL_IMPORTERS_IMUCAL_CSV_H_
#define IMUCAL_IMPORTERS_IMUCAL_CSV_H_

#include <string>
#include <string_view>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "core/capture.h"
#include "importers/registry.h"

namespace imucal::importers {

// The marker that must be the first line of an imucal capture.
inline constexpr std::string_view kImucalCaptureMarker = "# imucal-capture v1";

// Parses the text of an imucal capture. `source_name` prefixes error messages (usually the path).
// Accepts LF or CRLF line endings, blank lines anywhere, a UTF-8 byte-order mark, spaces around
// fields and header keys/values. Every '#' line before the column line must be key=value (a bare
// '#' counts as blank). Unknown header keys go to `extra_metadata` in file order; columns other
// than t,ax,ay,az,gx,gy,gz,temp go to `extra_columns` in file order. A capture with a column line
// and no rows is valid (and empty).
// A compatible extension of the spec: the gyro columns gx,gy,gz are required together or absent
// together; without them the capture is accelerometer-only (core::Capture::has_gyro false) and
// the gyro_unit header is optional. FormatImucalCsv writes such a capture the same way.
absl::StatusOr<core::Capture> ParseImucalCsv(std::string_view text, std::string_view source_name);

// Reads `path` with one read and parses it; errors are prefixed with `path`.
absl::StatusOr<core::Capture> ReadImucalCsvFile(const std::string& path);

// Formats a capture as imucal CSV. Values use the shortest text that parses back to the same
// double (std::to_chars), so Parse(Format(c)) == c exactly. Header order: marker, device (if
// non-empty), accel_unit, gyro_unit, gravity, rate_hz (if > 0), temp_unit (if the capture has
// temperature or a non-default temp unit), then extra_metadata; columns t,ax,ay,az,gx,gy,gz,
// [temp], then the extra columns.
// Precondition: CheckCaptureWritable(capture) is OK (WriteImucalCsvFile checks it); otherwise
// the output is unspecified but memory-safe.
std::string FormatImucalCsv(const core::Capture& capture);

// ValidateCapture plus what the text format needs: metadata keys and values and column names
// that survive a round trip (no line breaks, no ',' in column names, no '=' in keys, no
// duplicate or reserved names).
absl::Status CheckCaptureWritable(const core::Capture& capture);

// Writes FormatImucalCsv(capture) to `path` + ".tmp", then renames it over `path`, so `path`
// either keeps its old content or gets the complete new one. The temp file is removed on failure.
absl::Status WriteImucalCsvFile(const core::Capture& capture, const std::string& path);

// The "imucal" importer for the registry (one file; auto-detected by its marker line). The
// ImportOptions overrides replace the file's own header values, with a note for each change.
const CaptureImporter* ImucalCsvImporter();

}  // namespace imucal::importers

#endif  // IMUCAL_IMPORTERS_IMUCAL_CSV_H_
