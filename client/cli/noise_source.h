// `imucal noise`: where the samples come from. The command (noise_command.cc, in imucal_cli)
// reads rest recordings with the importers; a robot's stored session on the server
// (`--session S`) is read by noise_session.cc, in imucal_cli_server, which has the server's API,
// and handed to the same code path.
#ifndef IMUCAL_CLIENT_CLI_NOISE_SOURCE_H_
#define IMUCAL_CLIENT_CLI_NOISE_SOURCE_H_

#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "core/capture.h"
#include "importers/registry.h"

namespace imucal::cli {

// A stored session, where it was read from.
struct NoiseSession {
  std::string id;
  std::string device;
  std::string server;  // the address it was read from
};

// The samples `imucal noise` analyses, in their input units, and what was read.
struct NoiseInput {
  core::Capture capture;
  importers::ImportReport report;  // format, what was read (paths), notes
  std::optional<NoiseSession> session;
};

// Reads session `session_id` from the server at `server` (nullopt: $IMUCAL_SERVER, else the
// default) into `*input`: the capture in the device's registered units, with the standard
// gravity that a file import defaults to. Returns kExitOk, or the exit code of the error it has
// printed (as the server commands map them: 2 unknown session, 6 unreachable, 7 refused).
using NoiseSessionReader = std::function<int(
    const std::string& session_id, const std::optional<std::string>& server, NoiseInput* input)>;

// `imucal noise` with its samples from files or, given --session, from `read_session` (which
// may be empty where no server is linked: --session is then refused).
int RunNoiseWith(const std::vector<std::string>& args, const NoiseSessionReader& read_session);

}  // namespace imucal::cli

#endif  // IMUCAL_CLIENT_CLI_NOISE_SOURCE_H_
