// The input-format flags shared by `calibrate`, `apply` and `upload`: the column-mapped CSV
// (--columns and its time base) and the ROS 2 bag topic, so that every command reads every
// format the same way.
#ifndef IMUCAL_CLIENT_CLI_IMPORT_FLAGS_H_
#define IMUCAL_CLIENT_CLI_IMPORT_FLAGS_H_

#include <set>
#include <string>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "client/cli/args.h"
#include "importers/registry.h"

namespace imucal::cli {

// For --help, after a command's own options.
extern const char kImportFlagsHelp[];

// `flags` plus the importer flags that take a value / the importer switches.
std::set<std::string> WithImportValuedFlags(std::set<std::string> flags);
std::set<std::string> WithImportSwitches(std::set<std::string> switches);

// Reads the importer flags into `options`. A bad value, or a column option without --columns, is
// InvalidArgument naming the flag (a usage error).
absl::Status ApplyImportFlags(const Args& args, importers::ImportOptions* options);

// Reads --format, --accel-unit and --gyro-unit into `options`. A unit it does not know is
// InvalidArgument naming the flag.
absl::Status ApplyFormatAndUnitFlags(const Args& args, importers::ImportOptions* options);

// The import options of a command's flags: --format, --accel-unit, --gyro-unit, --gravity,
// --device and the importer flags (ApplyImportFlags). InvalidArgument naming the flag.
absl::StatusOr<importers::ImportOptions> ImportOptionsFrom(const Args& args);

}  // namespace imucal::cli

#endif  // IMUCAL_CLIENT_CLI_IMPORT_FLAGS_H_
