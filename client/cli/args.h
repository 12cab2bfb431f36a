// A small argument parser for the imucal CLI: positionals plus `--name value`, `--name=value`
// and boolean `--flag`. Every flag a command reads is declared, so an unknown or misspelt flag
// is an error that names it rather than being ignored.
#ifndef IMUCAL_CLIENT_CLI_ARGS_H_
#define IMUCAL_CLIENT_CLI_ARGS_H_

#include <map>
#include <optional>
#include <set>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"

namespace imucal::cli {

class Args {
 public:
  // `valued` flags take a value; `switches` do not.
  static absl::StatusOr<Args> Parse(const std::vector<std::string>& argv,
                                    const std::set<std::string>& valued,
                                    const std::set<std::string>& switches) {
    Args a;
    for (size_t i = 0; i < argv.size(); ++i) {
      const std::string& s = argv[i];
      if (s.rfind("--", 0) != 0 || s == "--") {
        a.positional_.push_back(s);
        continue;
      }
      std::string name = s.substr(2), value;
      const size_t eq = name.find('=');
      const bool has_eq = eq != std::string::npos;
      if (has_eq) {
        value = name.substr(eq + 1);
        name = name.substr(0, eq);
      }
      if (switches.count(name)) {
        if (has_eq) return absl::InvalidArgumentError(absl::StrCat("--", name, " takes no value"));
        a.switches_.insert(name);
      } else if (valued.count(name)) {
        if (!has_eq) {
          if (i + 1 >= argv.size())
            return absl::InvalidArgumentError(absl::StrCat("--", name, " needs a value"));
          value = argv[++i];
        }
        a.values_[name] = value;
        a.all_values_[name].push_back(value);
      } else {
        return absl::InvalidArgumentError(absl::StrCat("unknown flag --", name));
      }
    }
    return a;
  }

  const std::vector<std::string>& positional() const { return positional_; }
  bool Has(const std::string& name) const { return switches_.count(name) || values_.count(name); }
  std::optional<std::string> Get(const std::string& name) const {
    auto it = values_.find(name);
    return it == values_.end() ? std::nullopt : std::optional<std::string>(it->second);
  }
  // Every value of a repeatable flag, in order (Get returns the last).
  std::vector<std::string> GetAll(const std::string& name) const {
    auto it = all_values_.find(name);
    return it == all_values_.end() ? std::vector<std::string>{} : it->second;
  }
  absl::StatusOr<double> GetDouble(const std::string& name, double fallback) const {
    auto v = Get(name);
    if (!v) return fallback;
    double d;
    if (!absl::SimpleAtod(*v, &d))
      return absl::InvalidArgumentError(absl::StrCat("--", name, ": '", *v, "' is not a number"));
    return d;
  }
  absl::StatusOr<int64_t> GetInt(const std::string& name, int64_t fallback) const {
    auto v = Get(name);
    if (!v) return fallback;
    int64_t d;
    if (!absl::SimpleAtoi(*v, &d))
      return absl::InvalidArgumentError(absl::StrCat("--", name, ": '", *v, "' is not an integer"));
    return d;
  }

 private:
  std::vector<std::string> positional_;
  std::map<std::string, std::string> values_;
  std::map<std::string, std::vector<std::string>> all_values_;
  std::set<std::string> switches_;
};

}  // namespace imucal::cli

#endif  // IMUCAL_CLIENT_CLI_ARGS_H_
