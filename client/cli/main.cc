// imucal: the technician's command-line tool. Offline commands work on files; server commands
// come with the calibration service.
#include <cstdio>
#include <string>
#include <vector>

#include "client/cli/commands.h"

namespace {

constexpr char kHelp[] =
    "usage: imucal COMMAND [options]   (imucal COMMAND --help for each)\n"
    "offline commands:\n"
    "  calibrate FILE...        calibrate accelerometer and gyroscope from a capture\n"
    "  apply --params P IN OUT  apply a parameter set to a capture (writes m/s^2, rad/s)\n"
    "  simulate --out FILE      write a simulated capture with known truth\n"
    "  demo                     simulate, calibrate, apply, print the error before and after\n";

}  // namespace

int main(int argc, char** argv) {
  if (argc < 2) {
    std::fputs(kHelp, stderr);
    return imucal::cli::kExitUsage;
  }
  const std::string command = argv[1];
  const std::vector<std::string> args(argv + 2, argv + argc);
  if (command == "--help" || command == "-h" || command == "help") {
    std::fputs(kHelp, stdout);
    return imucal::cli::kExitOk;
  }
  if (command == "--version") {
    std::puts("imucal " IMUCAL_VERSION);
    return imucal::cli::kExitOk;
  }
  if (command == "calibrate") return imucal::cli::RunCalibrate(args);
  if (command == "apply") return imucal::cli::RunApply(args);
  if (command == "simulate") return imucal::cli::RunSimulate(args);
  if (command == "demo") return imucal::cli::RunDemo(args);
  std::fprintf(stderr, "imucal: unknown command '%s'\n\n%s", command.c_str(), kHelp);
  return imucal::cli::kExitUsage;
}
