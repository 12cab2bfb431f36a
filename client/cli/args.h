// The imucal CLI's parsed arguments: util/flags.h (CLI11), shared with imucald and the
// benchmarks. Each command's flags are declared in client/cli/command_table.cc.
#ifndef IMUCAL_CLIENT_CLI_ARGS_H_
#define IMUCAL_CLIENT_CLI_ARGS_H_

#include "util/flags.h"

namespace imucal::cli {

using Args = flags::Args;

}  // namespace imucal::cli

#endif  // IMUCAL_CLIENT_CLI_ARGS_H_
