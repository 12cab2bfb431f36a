// Reading a capture from files: the import options, the CaptureImporter interface that each
// format implements, and the registry that picks the format (ImportCapture). The formats:
//   imucal   importers/imucal_csv.h  the imucal capture CSV (../shared/spec/capture-format.md)
//   euroc    importers/euroc.h       EuRoC / ASL imu0/data.csv
//   imutk    importers/imutk.h       the imu_tk ASCII pair (units: importers/unit_inference.h)
//   columns  importers/columns.h     a delimited vendor CSV whose columns the user names
//   rosbag2  importers/rosbag2.h     a ROS 2 bag (sqlite3 or mcap storage), sensor_msgs/msg/Imu
//   mcap     importers/mcap.h        a bare ROS 2 .mcap file, sensor_msgs/msg/Imu
//
// Every reader either returns a complete, valid Capture (ValidateCapture holds) or an error:
// nothing is half-imported. Data errors are InvalidArgument with a message that starts
// "SOURCE:LINE: " and names the column and the offending text, e.g.
//   cap.csv:17: column 'az': 'abc' is not a number
// File-system errors keep their errno-derived code (NotFound, PermissionDenied, ...).
#ifndef IMUCAL_IMPORTERS_REGISTRY_H_
#define IMUCAL_IMPORTERS_REGISTRY_H_

#include <cstddef>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "core/capture.h"

namespace imucal::importers {

// ---------------------------------------------------------------------------------------------
// Import options.

// Time base of the column-mapped CSV importer (importers/columns.h).
enum class ColumnTimeUnit { kSeconds, kMilliseconds, kMicroseconds, kNanoseconds, kSampleIndex };

// Options of the column-mapped CSV importer ("columns"; importers/columns.h documents them).
struct ColumnCsvOptions {
  // "ax=NAME,ay=NAME,az=NAME[,gx=NAME,gy=NAME,gz=NAME][,t=NAME][,temp=NAME]"; NAME is a header
  // name or a 1-based column number; without gx, gy, gz the capture is accelerometer-only.
  // Empty: not configured (then "auto" never picks "columns").
  std::string map;
  ColumnTimeUnit time_unit = ColumnTimeUnit::kSeconds;  // of the t column
  std::optional<double> rate_hz;   // sample rate: needed without a t column or with kSampleIndex
  std::string rate_from_preamble;  // or: the preamble key ("Fs" in "Fs,100") that holds it
  std::optional<int> skip_lines;   // lines before the header; default: found by the names
  std::string delimiter;           // ",", ";", "tab", "space"; empty: detected from the header
  bool no_header = false;          // the file has no header line (NAME must be a number)
  bool sort_by_time = false;       // rows out of time order are sorted instead of an error
  // Rows that leave a mapped column empty (an interleaved log: each row fills one sensor's
  // columns) are skipped and counted in a note, instead of an error.
  bool skip_incomplete_rows = false;
  std::optional<core::TempUnit> temp_unit;
};

struct ImportOptions {
  // "auto" (detect from the content), or the name of an importer: "imucal", "euroc", "imutk",
  // "columns", "rosbag2", "mcap".
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
  // Threads an import may use (an IMU-TK pair's two files are parsed side by side); 1 in the
  // server.
  int threads = 1;
};

// What an import decided on its own, for the CLI to show the user.
struct ImportReport {
  std::string format;              // the importer that read the files: "imucal", "imutk"
  std::vector<std::string> paths;  // the paths in the order they were used (after any swap)
  std::vector<std::string> notes;  // one sentence each: inferred units, swapped files, overrides
};

// ---------------------------------------------------------------------------------------------
// Importers.
//
// One CaptureImporter per format. To add a format, implement this interface and append it to the
// list in registry.cc: ImportCapture, the CLI's --format and its auto-detection pick it up with
// no caller changes.
class CaptureImporter {
 public:
  virtual ~CaptureImporter() = default;

  // The --format name, e.g. "imutk".
  virtual std::string_view name() const = 0;
  // How many paths make one capture: 1, or 2 for imutk's pair. ImportCapture reads more paths
  // as several captures joined (JoinCaptures).
  virtual size_t paths_per_capture() const { return 1; }
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

// The importers, in auto-detection order: "imucal", "euroc", "imutk", "columns" (never
// auto-detected: it needs ImportOptions::columns), "rosbag2", "mcap".
std::span<const CaptureImporter* const> CaptureImporters();

// Reads a capture from `paths` with the importer named by options.format, or for "auto"
// "columns" when options.columns.map is set, else the first importer whose Sniff accepts the
// content (a directory's head is empty: importers of directories look at the path):
//   first line "# imucal-capture"  -> imucal (one file);
//   first line "#timestamp [ns],w_RS_S_x ..." -> euroc (one file);
//   lines of exactly four numbers  -> imutk (two files: accelerometer, then gyroscope; if the
//                                     file names say "gyr" then "acc", they are swapped back and
//                                     a note says so);
//   a directory with metadata.yaml, or a file that starts with the SQLite header -> rosbag2;
//   a file that starts with the MCAP magic -> mcap.
// If nothing matches, InvalidArgument names the file and what each format expected. If `report`
// is non-null it receives the format used and the notes (only on success).
// More paths than the format reads for one capture (several files, bags, or imutk pairs) are
// read one capture each, with the same options, and joined in the given order (JoinCaptures).
// Auto-detection then looks at the first capture's paths.
absl::StatusOr<core::Capture> ImportCapture(const std::vector<std::string>& paths,
                                            const ImportOptions& options,
                                            ImportReport* report = nullptr);

// ---------------------------------------------------------------------------------------------
// Shared by the importers' implementations.

// InvalidArgument "the FORMAT format reads one WHAT, got N: PATH, PATH" unless `paths` holds
// exactly one path (WHAT: "file", "bag").
absl::Status CheckOnePath(std::string_view format, std::string_view what,
                          const std::vector<std::string>& paths);

// Checks the options every importer reads (a gravity override must be a positive number).
absl::Status CheckImportOptions(const ImportOptions& options);

// Applies the device/unit/gravity overrides of `options` to a capture read from a file that
// states its own values, noting every value that changes.
void ApplyImportOverrides(const ImportOptions& options, core::Capture* capture,
                          std::vector<std::string>* notes);

// One capture from several, in order: each file keeps its own header and time base. File k's
// times follow file k - 1's last sample after an unmeasured gap of at least 1 s (or 10 median
// intervals): kept as they are when they already do (absolute time), shifted otherwise (a time
// base restarting at 0). The gap is a file start (core::Capture::files): nothing is integrated
// across it and no pose spans it. The captures must agree on units (InvalidArgument naming the
// files that differ); temperature and extra columns are kept only when every file has them (a
// note says what was dropped). Device, gravity and metadata are the first file's.
absl::StatusOr<core::Capture> JoinCaptures(std::vector<core::Capture> parts,
                                           std::vector<std::string>* notes);

// Appends a note when `capture` has time gaps (an interval over 3x the median interval): how
// many, and the largest with its time. For the importers whose time comes from the file.
void NoteTimeGaps(const core::Capture& capture, std::vector<std::string>* notes);

}  // namespace imucal::importers

#endif  // IMUCAL_IMPORTERS_REGISTRY_H_
