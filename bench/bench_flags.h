// The benchmarks' command-line flags, on CLI11 (Debian libcli11-dev) directly: each bench binds
// its Flags struct with `app.add_option("--name", flags.field, "what, in which unit")` and
// calls ParseBenchFlags, so `-h`/`--help` lists its flags, `--name=value` and `--name value`
// both work, and a flag it does not know is an error that names it.
// (imucal and imucald parse through util/flags.h, which serves their commands and subcommands.)
#ifndef IMUCAL_BENCH_BENCH_FLAGS_H_
#define IMUCAL_BENCH_BENCH_FLAGS_H_

#include <CLI/CLI.hpp>

#include <cstdlib>

namespace imucal::bench {

// Every option of `app` shows its present value, the default, in the help, and keeps its last
// value when it is given twice, as the hand-written parsers did (a comma list given twice gets
// both lists). ParseBenchFlags calls it; a bench that prints the help some other way
// (calibration_bench, through Google Benchmark's --help) calls it once its options are added.
inline void ShowDefaultsTakeLast(CLI::App& app) {
  for (CLI::Option* option : app.get_options()) {
    if (option->get_expected_max() == 1) {
      option->capture_default_str()->multi_option_policy(CLI::MultiOptionPolicy::TakeLast);
    } else if (option->get_items_expected_max() > 1) {
      option->capture_default_str();  // a list
    }
  }
}

// Parses argv into the options of `app`; returns only if they parsed. `-h`/`--help` prints the
// help and exits 0; a parse error (an unknown flag, a missing or malformed value: CLI11's
// message, e.g. "The following argument was not expected: --x") exits 2.
inline void ParseBenchFlags(CLI::App& app, int argc, char** argv) {
  ShowDefaultsTakeLast(app);
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    std::exit(app.exit(e) == 0 ? 0 : 2);
  }
}

}  // namespace imucal::bench

#endif  // IMUCAL_BENCH_BENCH_FLAGS_H_
