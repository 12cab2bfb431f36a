// Reading and writing captures: the imucal CSV format (../shared/spec/capture-format.md), the
// imu_tk ASCII pair, and a small importer registry that picks the format for the CLI.
//
// Every reader either returns a complete, valid Capture (ValidateCapture holds) or an error:
// nothing is half-imported. Data errors are InvalidArgument with a message that starts
// "SOURCE:LINE: " and names the column and the offending text, e.g.
//   cap.csv:17: column 'az': 'abc' is not a number
// File-system errors keep their errno-derived code (NotFound, PermissionDenied, ...).
#ifndef IMUCAL_IMPORTERS_CAPTURE_IO_H_
#define IMUCAL_IMPORTERS_CAPTURE_IO_H_

#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "Eigen/Core"
#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "core/capture.h"

namespace imucal::importers {

// ---------------------------------------------------------------------------------------------
// imucal capture CSV, version 1.

// The marker that must be the first line of an imucal capture.
inline constexpr std::string_view kImucalCaptureMarker = "# imucal-capture v1";

// Parses the text of an imucal capture. `source_name` prefixes error messages (usually the path).
// Accepts LF or CRLF line endings, blank lines anywhere, a UTF-8 byte-order mark, spaces around
// fields and header keys/values. Every '#' line before the column line must be key=value (a bare
// '#' counts as blank). Unknown header keys go to `extra_metadata` in file order; columns other
// than t,ax,ay,az,gx,gy,gz,temp go to `extra_columns` in file order. A capture with a column line
// and no rows is valid (and empty).
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

// ---------------------------------------------------------------------------------------------
// Import options and unit inference.

// Time base of the column-mapped CSV importer (core/import_columns.h).
enum class ColumnTimeUnit { kSeconds, kMilliseconds, kMicroseconds, kNanoseconds, kSampleIndex };

// Options of the column-mapped CSV importer ("columns"; core/import_columns.h documents them).
struct ColumnCsvOptions {
  // "ax=NAME,ay=NAME,az=NAME,gx=NAME,gy=NAME,gz=NAME[,t=NAME][,temp=NAME]"; NAME is a header
  // name or a 1-based column number. Empty: not configured (then "auto" never picks "columns").
  std::string map;
  ColumnTimeUnit time_unit = ColumnTimeUnit::kSeconds;  // of the t column
  std::optional<double> rate_hz;   // sample rate: needed without a t column or with kSampleIndex
  std::string rate_from_preamble;  // or: the preamble key ("Fs" in "Fs,100") that holds it
  std::optional<int> skip_lines;   // lines before the header; default: found by the names
  std::string delimiter;           // ",", ";", "tab", "space"; empty: detected from the header
  bool no_header = false;          // the file has no header line (NAME must be a number)
  bool sort_by_time = false;       // rows out of time order are sorted instead of an error
  std::optional<core::TempUnit> temp_unit;
};

struct ImportOptions {
  // "auto" (detect from the content), or the name of a registered importer: "imucal", "imutk",
  // "euroc", "columns", "rosbag2" (when registered).
  std::string format = "auto";
  // Units to use instead of the file's own (imucal) or the inferred ones (imutk).
  std::optional<core::AccelUnit> accel_unit;
  std::optional<core::GyroUnit> gyro_unit;
  // Local gravity magnitude, m/s^2, instead of the file's or the 9.80665 default.
  std::optional<double> gravity_m_s2;
  // Device id instead of the file's (the CLI's --device).
  std::optional<std::string> device;
  // The column-mapped CSV importer's options; a non-empty `columns.map` makes "auto" use it.
  ColumnCsvOptions columns;
  // ROS 2 bag: the sensor_msgs/msg/Imu topic to read; empty: the bag's only Imu topic.
  std::string topic;
};

// What an import decided on its own, for the CLI to show the user.
struct ImportReport {
  std::string format;              // the importer that read the files: "imucal", "imutk"
  std::vector<std::string> paths;  // the paths in the order they were used (after any swap)
  std::vector<std::string> notes;  // one sentence each: inferred units, swapped files, overrides
};

// Unit inference for formats that carry no units (imu_tk), applied unless ImportOptions names
// the unit. The rule, and why:
//
// Accelerometer: m = median over samples of |a| (the magnitude, so it is the same whichever
// face is up; most samples of a calibration capture are static, where |a| is about g).
//   |m - g| <= 0.3 g   -> m/s^2   (g = the capture's gravity, 9.80665 by default)
//   |m - 1| <= 0.3     -> g
//   otherwise          -> counts  (e.g. unsigned 16-bit around 32768, or 16384 LSB/g)
// The 30% band admits uncalibrated sensors (scale and bias errors of a few percent) and hand
// motion; the bands are far apart, so a sensor cannot fall into the wrong one.
//
// Gyroscope, in order:
//   1. the accelerometer is counts, and the gyro values are either all integers or have a
//      median |value| (over all components) above 50 -> counts (raw registers: no rate in rad/s
//      or deg/s has a median of 50 during a mostly static capture);
//   2. the 99th percentile of |w| (the rate magnitude) exceeds 20 -> deg/s (hand rotation reaches
//      tens to hundreds of deg/s, while 20 rad/s = 1150 deg/s is beyond a hand-held capture);
//   3. otherwise -> rad/s. A capture without rotation cannot tell deg/s from rad/s; the note
//      says so, and ImportOptions::gyro_unit settles it.
core::AccelUnit InferAccelUnit(std::span<const Eigen::Vector3d> accel, double gravity_m_s2,
                               std::string* reason);
core::GyroUnit InferGyroUnit(std::span<const Eigen::Vector3d> gyro, core::AccelUnit accel_unit,
                             std::string* reason);

// ---------------------------------------------------------------------------------------------
// imu_tk ASCII pair: two files of lines "t x y z" (whitespace separated, no header), the
// accelerometer and the gyroscope, with the same timestamps on the same rows (equal to within
// 1 microsecond, the precision of the text). Blank lines are skipped. Units come from `options`
// or InferAccelUnit/InferGyroUnit; what was inferred is appended to `notes` if non-null.
absl::StatusOr<core::Capture> ParseImuTkPair(std::string_view accel_text,
                                             std::string_view accel_name,
                                             std::string_view gyro_text, std::string_view gyro_name,
                                             const ImportOptions& options,
                                             std::vector<std::string>* notes = nullptr);
absl::StatusOr<core::Capture> ReadImuTkPair(const std::string& accel_path,
                                            const std::string& gyro_path,
                                            const ImportOptions& options,
                                            std::vector<std::string>* notes = nullptr);

// ---------------------------------------------------------------------------------------------
// Importer registry.
//
// One CaptureImporter per external format. To add a format (EuRoC CSV, ROS 2 bag, column-mapped
// vendor CSV), implement this interface and append it to the list in capture_io.cc:
// ImportCapture, the CLI's --format and its auto-detection pick it up with no caller changes.
class CaptureImporter {
 public:
  virtual ~CaptureImporter() = default;

  // The --format name, e.g. "imutk".
  virtual std::string_view name() const = 0;
  // One line for --help, e.g. "imu_tk ASCII pair: accelerometer file, then gyroscope file".
  virtual std::string_view description() const = 0;

  // Whether the inputs look like this format. `heads[i]` is the start of paths[i] (at most
  // kSniffBytes; shorter only at end of file). Returns OK, or the reason it is not this format
  // (shown in the "unrecognised format" error, so phrase it for the user).
  virtual absl::Status Sniff(std::span<const std::string> paths,
                             std::span<const std::string> heads) const = 0;

  // Reads the inputs into a capture that satisfies ValidateCapture, applying `options`, and
  // appends to `notes` (never null) what it decided on its own. `paths` may be reordered by the
  // importer; it reports the order used in `used_paths` (never null).
  virtual absl::StatusOr<core::Capture> Import(const std::vector<std::string>& paths,
                                               const ImportOptions& options,
                                               std::vector<std::string>* used_paths,
                                               std::vector<std::string>* notes) const = 0;
};

// How much of each file auto-detection looks at.
inline constexpr size_t kSniffBytes = 4096;

// The registered importers, in auto-detection order: "imucal", "euroc", "imutk", "columns"
// (never auto-detected: it needs ImportOptions::columns), then those added by
// RegisterCaptureImporter in the order added.
std::span<const CaptureImporter* const> CaptureImporters();

// Adds an importer that lives outside core (e.g. storage's ROS 2 bag reader, which needs
// SQLite). Call it explicitly at start-up, before any import runs concurrently: no static
// initialiser does it, because the linker may drop an object file nothing references. Adding an
// importer whose name is already registered does nothing; `importer` must outlive the process.
void RegisterCaptureImporter(const CaptureImporter* importer);

// Reads a capture from `paths` with the importer named by options.format, or for "auto"
// "columns" when options.columns.map is set, else the first importer whose Sniff accepts the
// content (a directory's head is empty: importers of directories look at the path):
//   first line "# imucal-capture"  -> imucal (one file);
//   first line "#timestamp [ns],w_RS_S_x ..." -> euroc (one file);
//   lines of exactly four numbers  -> imutk (two files: accelerometer, then gyroscope; if the
//                                     file names say "gyr" then "acc", they are swapped back and
//                                     a note says so).
// If nothing matches, InvalidArgument names the file and what each format expected. If `report`
// is non-null it receives the format used and the notes (only on success).
absl::StatusOr<core::Capture> ImportCapture(const std::vector<std::string>& paths,
                                            const ImportOptions& options,
                                            ImportReport* report = nullptr);

}  // namespace imucal::importers

#endif  // IMUCAL_IMPORTERS_CAPTURE_IO_H_
