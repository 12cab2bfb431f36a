#include "util/flags.h"

#include <CLI/CLI.hpp>

#include <memory>

#include "absl/strings/numbers.h"
#include "util/str_util.h"

namespace imucal::flags {

absl::StatusOr<Args> Args::Parse(const std::vector<std::string>& argv,
                                 const std::set<std::string>& valued,
                                 const std::set<std::string>& switches,
                                 const std::set<std::string>& booleans) {
  CLI::App app;
  app.set_help_flag();  // "help" is an ordinary switch: each command prints its own text
  app.allow_extras(true);  // unknown flags are collected and named below, in our words
  app.positionals_at_end(false);
  Args args;
  for (const std::string& name : valued) {
    // One value per occurrence; every occurrence kept.
    app.add_option(Cat("--", name), args.values_[name])
        ->expected(1)
        ->multi_option_policy(CLI::MultiOptionPolicy::TakeAll)
        ->allow_extra_args(false);
  }
  std::map<std::string, CLI::Option*> boolean_options;
  for (const std::string& name : booleans) {
    boolean_options[name] = app.add_option(Cat("--", name), args.values_[name])
                                ->expected(0, 1)
                                ->multi_option_policy(CLI::MultiOptionPolicy::TakeAll)
                                ->allow_extra_args(false);
  }
  std::map<std::string, std::unique_ptr<bool>> given;
  for (const std::string& name : switches) {
    given[name] = std::make_unique<bool>(false);
    app.add_flag(name == "help" ? "-h,--help" : Cat("--", name), *given[name]);
  }
  app.add_option("positional", args.positional_);
  // CLI11 parses right to left from a reversed vector.
  std::vector<std::string> reversed(argv.rbegin(), argv.rend());
  try {
    app.parse(reversed);
  } catch (const CLI::ArgumentMismatch& e) {
    // A valued flag with nothing after it. CLI11 names the option first: "--out: ...".
    const std::string what = e.what();
    const std::string flag = what.substr(0, what.find(':'));
    return absl::InvalidArgumentError(flag.starts_with("--") ? Cat(flag, " needs a value") : what);
  } catch (const CLI::ConversionError& e) {
    return absl::InvalidArgumentError(Cat(e.what(), " (a switch takes true or false)"));
  } catch (const CLI::ParseError& e) {
    return absl::InvalidArgumentError(e.what());
  }
  // What CLI11 did not match: unknown flags, and every word after `--` (positionals).
  bool after_double_dash = false;
  for (const std::string& extra : app.remaining()) {
    if (!after_double_dash && extra == "--") {
      after_double_dash = true;
    } else if (!after_double_dash && extra.starts_with("-")) {
      return absl::InvalidArgumentError(Cat("unknown flag ", extra.substr(0, extra.find('='))));
    } else {
      args.positional_.push_back(extra);
    }
  }
  for (auto& [name, on] : given) {
    if (*on) args.switches_.insert(name);
  }
  for (const auto& [name, option] : boolean_options) {
    // Given bare: true (CLI11 records an empty value, or none).
    std::vector<std::string>& values = args.values_[name];
    for (std::string& value : values) {
      if (value.empty()) value = "true";
    }
    if (option->count() > 0 && values.empty()) values.push_back("true");
  }
  std::erase_if(args.values_, [](const auto& entry) { return entry.second.empty(); });
  return args;
}

bool Args::Has(const std::string& name) const {
  return switches_.contains(name) || values_.contains(name);
}

std::optional<std::string> Args::Get(const std::string& name) const {
  const auto it = values_.find(name);
  if (it == values_.end()) return std::nullopt;
  return it->second.back();
}

std::vector<std::string> Args::GetAll(const std::string& name) const {
  const auto it = values_.find(name);
  return it == values_.end() ? std::vector<std::string>{} : it->second;
}

absl::StatusOr<double> Args::GetDouble(const std::string& name, double fallback) const {
  const std::optional<std::string> v = Get(name);
  if (!v) return fallback;
  double d;
  if (!absl::SimpleAtod(*v, &d)) {
    return absl::InvalidArgumentError(Cat("--", name, ": '", *v, "' is not a number"));
  }
  return d;
}

absl::StatusOr<int64_t> Args::GetInt(const std::string& name, int64_t fallback) const {
  const std::optional<std::string> v = Get(name);
  if (!v) return fallback;
  int64_t i;
  if (!absl::SimpleAtoi(*v, &i)) {
    return absl::InvalidArgumentError(Cat("--", name, ": '", *v, "' is not an integer"));
  }
  return i;
}

}  // namespace imucal::flags
