#include "client/cli/import_flags.h"

#include <set>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/strings/str_cat.h"
#include "core/capture.h"
#include "importers/columns.h"

namespace imucal::cli {

const char kImportFlagsHelp[] =
    "input formats (--format, default auto): imucal CSV, EuRoC imu0/data.csv, imu_tk pair,\n"
    "  ROS 2 bag (directory with metadata.yaml, sqlite3 or mcap storage; a .db3 or .mcap file),\n"
    "  and vendor CSV with --columns:\n"
    "  --columns ax=C,ay=C,az=C[,gx=C,gy=C,gz=C][,t=C][,temp=C]   C: header name or column "
    "number;\n"
    "                    without gx,gy,gz: an accelerometer-only capture\n"
    "  --time-unit s|ms|us|ns|index   unit of the t column (index: a sample counter; needs a "
    "rate)\n"
    "  --rate HZ | --rate-from-preamble KEY   sample rate (needed without t, or with index)\n"
    "  --skip-lines N    preamble lines before the header (default: up to the line naming the "
    "columns)\n"
    "  --delimiter ,|;|tab|space   (default: detected)   --no-header   columns by number only\n"
    "  --sort-time       sort rows by time (a file saved part by part) instead of an error\n"
    "  --skip-incomplete-rows   skip (and count) rows that leave a mapped column empty, as an\n"
    "                    interleaved log of several sensors writes them, instead of an error\n"
    "  --temp-unit C|counts\n"
    "  --topic NAME      ROS 2 bag: the sensor_msgs/msg/Imu topic (default: the only one)\n";

namespace {

const std::vector<std::string> kColumnValued = {
    "columns", "time-unit", "rate", "rate-from-preamble", "skip-lines", "delimiter", "temp-unit"};
const std::vector<std::string> kColumnSwitches = {"no-header", "sort-time", "skip-incomplete-rows"};

absl::Status FlagError(const std::string& flag, absl::string_view message) {
  return absl::InvalidArgumentError(absl::StrCat("--", flag, ": ", message));
}

}  // namespace

std::set<std::string> WithImportValuedFlags(std::set<std::string> flags) {
  flags.insert(kColumnValued.begin(), kColumnValued.end());
  flags.insert("topic");
  return flags;
}

std::set<std::string> WithImportSwitches(std::set<std::string> switches) {
  switches.insert(kColumnSwitches.begin(), kColumnSwitches.end());
  return switches;
}

absl::Status ApplyFormatAndUnitFlags(const Args& a, importers::ImportOptions* o) {
  if (auto f = a.Get("format")) o->format = *f;
  if (auto u = a.Get("accel-unit")) {
    auto p = core::ParseAccelUnit(*u);
    if (!p.ok())
      return absl::InvalidArgumentError(absl::StrCat("--accel-unit: ", p.status().message()));
    o->accel_unit = *p;
  }
  if (auto u = a.Get("gyro-unit")) {
    auto p = core::ParseGyroUnit(*u);
    if (!p.ok())
      return absl::InvalidArgumentError(absl::StrCat("--gyro-unit: ", p.status().message()));
    o->gyro_unit = *p;
  }
  return absl::OkStatus();
}

absl::Status ApplyImportFlags(const Args& a, importers::ImportOptions* o) {
  if (auto topic = a.Get("topic")) o->topic = *topic;
  const auto columns = a.Get("columns");
  if (!columns) {
    for (const auto* list : {&kColumnValued, &kColumnSwitches}) {
      for (const std::string& flag : *list) {
        if (a.Has(flag)) return FlagError(flag, "applies to --columns input only");
      }
    }
    return absl::OkStatus();
  }
  importers::ColumnCsvOptions& c = o->columns;
  c.map = *columns;
  if (auto unit = a.Get("time-unit")) {
    auto parsed = importers::ParseColumnTimeUnit(*unit);
    if (!parsed.ok()) return FlagError("time-unit", parsed.status().message());
    c.time_unit = *parsed;
  }
  if (a.Get("rate")) {
    auto rate = a.GetDouble("rate", 0);
    if (!rate.ok()) return rate.status();
    c.rate_hz = *rate;
  }
  if (auto key = a.Get("rate-from-preamble")) c.rate_from_preamble = *key;
  if (a.Get("skip-lines")) {
    auto skip = a.GetInt("skip-lines", 0);
    if (!skip.ok()) return skip.status();
    if (*skip < 0 || *skip > 1000000) return FlagError("skip-lines", "expected 0..1000000");
    c.skip_lines = static_cast<int>(*skip);
  }
  if (auto d = a.Get("delimiter")) c.delimiter = *d;
  if (auto unit = a.Get("temp-unit")) {
    auto parsed = core::ParseTempUnit(*unit);
    if (!parsed.ok()) return FlagError("temp-unit", parsed.status().message());
    c.temp_unit = *parsed;
  }
  c.no_header = a.Has("no-header");
  c.sort_by_time = a.Has("sort-time");
  c.skip_incomplete_rows = a.Has("skip-incomplete-rows");
  if (o->format != "auto" && o->format != "columns") {
    return FlagError("columns", absl::StrCat("needs --format columns or auto, not ", o->format));
  }
  return importers::CheckColumnCsvOptions(c);
}

}  // namespace imucal::cli
