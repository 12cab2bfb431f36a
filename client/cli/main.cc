// imucal: the technician's command-line tool. Offline commands work on files; server commands
// come with the calibration service.
#include <cstdio>
#include <string>
#include <utility>
#include <vector>

#include "client/cli/command_table.h"
#include "client/cli/commands.h"

namespace {

using imucal::cli::BashCompletion;
using imucal::cli::ZshCompletion;

constexpr char kHelp[] =
    "usage: imucal COMMAND [options]   (imucal help COMMAND, or imucal COMMAND -h, for each)\n"
    "offline commands:\n"
    "  calibrate FILE...        calibrate accelerometer and gyroscope from a capture\n"
    "  apply --params P IN OUT  apply a parameter set to a capture (writes m/s^2, rad/s)\n"
    "  simulate --out FILE      write a simulated capture with known truth\n"
    "  noise REST...            noise figures (N, B, K) of a rest recording; Kalibr and\n"
    "                           OpenVINS noise keys (or noise --session S: a stored session)\n"
    "  learn --train REC... --test REC... --out P.json   the gyro's dynamic block learnt from\n"
    "                           recordings with a reference orientation, gated on held-out ones\n"
    "  demo                     simulate, calibrate, apply, print the error before and after\n"
    "                           (with --server ADDR: the same through the service, guided)\n"
    "  export --params P --format F   a parameter set as json, kalibr, kalibr-intrinsics or\n"
    "                           openvins (Kalibr / OpenVINS YAML)\n"
    "server commands (imucal [--server ADDR] COMMAND ...; default $IMUCAL_SERVER, else\n"
    "127.0.0.1:50051; exit code 6 when the server is unreachable):\n"
    "  devices [register ID ...|get ID]   list, register or show devices\n"
    "  session start|list|show|cancel     calibration sessions\n"
    "  upload FILE... --device D          stream a capture into a session (resumes)\n"
    "  guide --device D                   live guidance through a calibration capture\n"
    "  solve --session S [--wait]         solve a session\n"
    "  report --session S [--json]        the latest solve's report\n"
    "  params get|list|promote|rollback   parameter versions of a device\n"
    "  export --device D --format F       a parameter version as json, kalibr,\n"
    "                                     kalibr-intrinsics or openvins\n"
    "  admin token create|list|revoke     API tokens (admin role)\n"
    "connection (any server command, anywhere on the line): --ca-cert PEM (CA of the server's\n"
    "TLS certificate, else $IMUCAL_CA_CERT), --token-file F or --token T (bearer token, else\n"
    "$IMUCAL_TOKEN_FILE or $IMUCAL_TOKEN); exit code 7 when the server refuses them;\n"
    "--tls-server-name N (the name its certificate holds, default the host dialled, or the first\n"
    "of an address list like ipv4:10.0.0.1:50051,10.0.0.2:50051; else $IMUCAL_TLS_SERVER_NAME)\n"
    "other:\n"
    "  help [COMMAND]           this text, or a command's\n"
    "  completion bash|zsh      a shell completion script (deploy/install.sh installs both)\n"
    "  --version                the version\n"
    "flags: --name value or --name=value; a switch alone (--json) or --json=false; -- ends the\n"
    "flags. An unknown flag is an error that names it (exit code 1).\n";

// Runs `command` with its arguments; kExitUsage for a word that is no command.
int Dispatch(const std::string& command, std::vector<std::string> args) {
  if (command == "calibrate") return imucal::cli::RunCalibrate(args);
  if (command == "apply") return imucal::cli::RunApply(args);
  if (command == "simulate") return imucal::cli::RunSimulate(args);
  if (command == "noise") return imucal::cli::RunNoise(args);
  if (command == "learn") return imucal::cli::RunLearn(args);
  if (command == "demo") {
    // With a server, the demo runs through the service; without, offline.
    for (const std::string& a : args)
      if (a == "--server" || a.rfind("--server=", 0) == 0) return imucal::cli::RunServerDemo(args);
    return imucal::cli::RunDemo(args);
  }
  if (command == "devices") return imucal::cli::RunDevices(args);
  if (command == "session") return imucal::cli::RunSession(args);
  if (command == "upload") return imucal::cli::RunUpload(args);
  if (command == "guide") return imucal::cli::RunGuide(args);
  if (command == "solve") return imucal::cli::RunSolve(args);
  if (command == "report") return imucal::cli::RunReport(args);
  if (command == "params") return imucal::cli::RunParams(args);
  if (command == "admin") return imucal::cli::RunAdmin(args);
  if (command == "export") {
    // A parameter set file (--params) is exported offline; a stored version (--device) by the
    // server. Without either, the offline help.
    bool has_device = false, has_params = false;
    for (const std::string& a : args) {
      has_device |= a == "--device" || a.rfind("--device=", 0) == 0;
      has_params |= a == "--params" || a.rfind("--params=", 0) == 0;
    }
    if (has_params || !has_device) return imucal::cli::RunExportFile(args);
    return imucal::cli::RunExport(args);
  }
  if (command == "completion") {
    const bool help = args.size() == 1 && (args[0] == "-h" || args[0] == "--help");
    const std::string shell = args.size() == 1 ? args[0] : "";
    if (shell == "bash" || shell == "zsh") {
      std::fputs((shell == "bash" ? BashCompletion() : ZshCompletion()).c_str(), stdout);
      return imucal::cli::kExitOk;
    }
    std::fputs("usage: imucal completion bash|zsh   (a completion script, on stdout)\n",
               help ? stdout : stderr);
    return help ? imucal::cli::kExitOk : imucal::cli::kExitUsage;
  }
  std::fprintf(stderr, "imucal: unknown command '%s'\n\n%s", command.c_str(), kHelp);
  return imucal::cli::kExitUsage;
}

}  // namespace

int main(int argc, char** argv) {
  // The connection flags may stand anywhere; they are taken out before the command parses its
  // own (server_common.cc keeps them for Connect).
  std::vector<std::string> all(argv, argv + argc);
  if (absl::Status s = imucal::cli::TakeConnectionFlags(&all); !s.ok()) {
    std::fprintf(stderr, "imucal: %s\n", std::string(s.message()).c_str());
    return imucal::cli::kExitUsage;
  }
  std::vector<char*> kept;
  for (std::string& a : all) kept.push_back(a.data());
  argc = static_cast<int>(kept.size());
  argv = kept.data();
  if (argc < 2) {
    std::fputs(kHelp, stderr);
    return imucal::cli::kExitUsage;
  }
  // A global `--server ADDR` (or --server=ADDR) before the command goes to the command.
  std::vector<std::string> global;
  int first = 1;
  while (first < argc) {
    const std::string s = argv[first];
    if (s == "--server" && first + 1 < argc) {
      global = {"--server", argv[first + 1]};
      first += 2;
    } else if (s.rfind("--server=", 0) == 0) {
      global = {s};
      first += 1;
    } else {
      break;
    }
  }
  if (first >= argc) {
    std::fputs(kHelp, stderr);
    return imucal::cli::kExitUsage;
  }
  const std::string command = argv[first];
  const std::vector<std::string> own(argv + first + 1, argv + argc);
  if (command == "--help" || command == "-h" || (command == "help" && own.empty())) {
    std::fputs(kHelp, stdout);
    return imucal::cli::kExitOk;
  }
  if (command == "help") {
    // help COMMAND: the command's own --help.
    if (own.size() != 1 || own[0].starts_with("-")) {
      std::fprintf(stderr, "imucal: usage: imucal help [COMMAND]\n");
      return imucal::cli::kExitUsage;
    }
    return Dispatch(own[0], {"--help"});
  }
  if (command == "--version") {
    std::puts("imucal " IMUCAL_VERSION);
    return imucal::cli::kExitOk;
  }
  std::vector<std::string> args = global;
  args.insert(args.end(), own.begin(), own.end());
  return Dispatch(command, std::move(args));
}
