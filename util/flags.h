// Command-line flags for imucal and imucald, parsed by CLI11 (Debian libcli11-dev) behind one
// small interface (the benchmarks use CLI11 directly, bench/bench_flags.h):
//
//   - positionals, plus `--name value` and `--name=value` for the flags that take a value (as
//     with getopt, the word after such a flag is its value, whatever it looks like);
//   - switches stand alone (`--json`), or take an explicit truth value (`--json=false`); a
//     boolean option stands alone or takes a value as the next word (`--insecure true`);
//   - a value that starts with '-' is taken as the value (`--gravity -9.81`); `--` ends the
//     flags, and every word after it is a positional;
//   - `-h` is `--help` wherever a command declares the switch "help";
//   - a flag the command does not declare is an error that names it ("unknown flag --jsn"), and
//     so is a valued flag at the end of the line ("--out needs a value").
//
// A flag may be given more than once: Get returns the last value, GetAll every value in order.
#ifndef IMUCAL_UTIL_FLAGS_H_
#define IMUCAL_UTIL_FLAGS_H_

#include <cstdint>
#include <map>
#include <optional>
#include <set>
#include <string>
#include <vector>

#include "absl/status/statusor.h"

namespace imucal::flags {

class Args {
 public:
  // `valued` flags take a value; `switches` do not. `booleans` (imucald's BOOL options) stand
  // alone, meaning "true", or take their value as `--name=false` or `--name false`: Get gives
  // the text, for the caller to parse. Names are without the leading "--".
  static absl::StatusOr<Args> Parse(const std::vector<std::string>& argv,
                                    const std::set<std::string>& valued,
                                    const std::set<std::string>& switches,
                                    const std::set<std::string>& booleans = {});

  const std::vector<std::string>& positional() const { return positional_; }
  // True for a switch that was given (and not given as `--name=false`), or a valued flag given.
  bool Has(const std::string& name) const;
  std::optional<std::string> Get(const std::string& name) const;
  // Every value of a repeatable flag, in order (Get returns the last).
  std::vector<std::string> GetAll(const std::string& name) const;
  // The flag's value as a number; `fallback` when it is absent. InvalidArgument naming the flag
  // and the text when it is not one.
  absl::StatusOr<double> GetDouble(const std::string& name, double fallback) const;
  absl::StatusOr<int64_t> GetInt(const std::string& name, int64_t fallback) const;

 private:
  std::vector<std::string> positional_;
  std::map<std::string, std::vector<std::string>> values_;
  std::set<std::string> switches_;
};

}  // namespace imucal::flags

#endif  // IMUCAL_UTIL_FLAGS_H_
