// The export flags shared by the offline `export --params` and the server's `export --device`:
// the topic, the rate, OpenVINS's model and noise values for figures a parameter set lacks.
#ifndef IMUCAL_CLIENT_CLI_EXPORT_FLAGS_H_
#define IMUCAL_CLIENT_CLI_EXPORT_FLAGS_H_

#include <set>
#include <string>

#include "absl/status/statusor.h"
#include "client/cli/args.h"
#include "core/export.h"

namespace imucal::cli {

// For --help, after a command's own options.
extern const char kExportOptionsHelp[];

// `flags` plus the export flags that take a value.
std::set<std::string> WithExportValuedFlags(std::set<std::string> flags);

// The options the flags give (unset values stay core::ExportOptions::kUnset). A bad value is
// InvalidArgument naming the flag.
absl::StatusOr<core::ExportOptions> ExportOptionsFrom(const Args& a);

}  // namespace imucal::cli

#endif  // IMUCAL_CLIENT_CLI_EXPORT_FLAGS_H_
