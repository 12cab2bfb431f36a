// Regressors of the extra error effects (report.md, "effects"): the signal an effect is
// proportional to, e.g. `temperature`, `ax*az`, `temperature^2`, `time`.
//
// Grammar (case-sensitive; spaces and tabs around a term are ignored):
//   regressor = term ('*' term)*        at most kMaxRegressorFactors factors in all
//   term      = signal | signal '^2'
//   signal    = temperature | time | ax | ay | az | gx | gy | gz
// Units: temperature degC; time s from capture start; ax..az specific force m/s^2; gx..gz rate
// rad/s (calibrated values in a solve, true values in the simulator).
//
// The parsed form is the multiset of factors, sorted in signal order, so `az*ax` and `ax*az` are
// the same regressor and Name() gives the canonical spelling: factors in signal order, each
// repeated pair written `s^2` (`ax*temperature*ax` -> `temperature*ax^2`).
//
// Header-only, standard library only: the robot SDK evaluates effects per sample with it.
// Evaluate() neither allocates nor throws.
#ifndef IMUCAL_CORE_REGRESSOR_H_
#define IMUCAL_CORE_REGRESSOR_H_

#include <array>
#include <optional>
#include <string>
#include <string_view>
#include <utility>

namespace imucal::core {

// Index of each signal in the array that Regressor::Evaluate reads. The order is fixed: the
// SDK and the solver fill one array per sample in this order.
enum class Signal : int {
  kTemperature = 0,  // degC
  kTime = 1,         // s from capture start
  kAx = 2,           // m/s^2
  kAy = 3,
  kAz = 4,
  kGx = 5,  // rad/s
  kGy = 6,
  kGz = 7,
};
inline constexpr int kNumSignals = 8;
inline constexpr std::array<std::string_view, kNumSignals> kSignalNames = {
    "temperature", "time", "ax", "ay", "az", "gx", "gy", "gz"};

// Most factors in one regressor (so a product of two squares fits).
inline constexpr int kMaxRegressorFactors = 4;

using SignalArray = std::array<double, kNumSignals>;

struct Regressor {
  // Signal indices (see Signal), sorted ascending; entries at and beyond num_factors are 0 so
  // that the defaulted == compares the factor multiset only.
  std::array<int, kMaxRegressorFactors> factors = {};
  int num_factors = 0;  // 0: the constant 1 (never produced by ParseRegressor; Name() is "")

  // Product of the factor signals. `signals` indexed by Signal.
  double Evaluate(const SignalArray& signals) const {
    double value = 1.0;
    for (int i = 0; i < num_factors; ++i) value *= signals[static_cast<size_t>(factors[i])];
    return value;
  }

  // The canonical name; ParseRegressor(Name()) == *this.
  std::string Name() const {
    std::string name;
    int i = 0;
    while (i < num_factors) {
      const int signal = factors[i];
      int run = 1;
      while (i + run < num_factors && factors[i + run] == signal) ++run;
      for (int k = 0; k < run; k += 2) {
        if (!name.empty()) name += '*';
        name += kSignalNames[static_cast<size_t>(signal)];
        if (k + 1 < run) name += "^2";
      }
      i += run;
    }
    return name;
  }

  friend bool operator==(const Regressor&, const Regressor&) = default;
};

namespace regressor_internal {

inline std::string_view Trim(std::string_view s) {
  const auto is_space = [](char c) { return c == ' ' || c == '\t'; };
  while (!s.empty() && is_space(s.front())) s.remove_prefix(1);
  while (!s.empty() && is_space(s.back())) s.remove_suffix(1);
  return s;
}

inline std::optional<int> SignalIndex(std::string_view name) {
  for (int i = 0; i < kNumSignals; ++i) {
    if (kSignalNames[static_cast<size_t>(i)] == name) return i;
  }
  return std::nullopt;
}

}  // namespace regressor_internal

// Parses a regressor name (grammar above). nullopt for anything else: an unknown signal, an
// empty term (`ax**az`, `ax*`), another power (`ax^3`), more than kMaxRegressorFactors factors.
inline std::optional<Regressor> ParseRegressor(std::string_view text) {
  Regressor regressor;
  while (true) {
    const size_t star = text.find('*');
    std::string_view term = regressor_internal::Trim(text.substr(0, star));
    int power = 1;
    if (term.size() >= 2 && term.substr(term.size() - 2) == "^2") {
      power = 2;
      term = regressor_internal::Trim(term.substr(0, term.size() - 2));
    }
    const std::optional<int> signal = regressor_internal::SignalIndex(term);
    if (!signal.has_value() || regressor.num_factors + power > kMaxRegressorFactors) {
      return std::nullopt;
    }
    for (int k = 0; k < power; ++k) regressor.factors[regressor.num_factors++] = *signal;
    if (star == std::string_view::npos) break;
    text.remove_prefix(star + 1);
  }
  // Insertion sort of at most four entries (std::sort trips GCC 12's -Warray-bounds here).
  for (int i = 1; i < regressor.num_factors; ++i) {
    for (int j = i; j > 0 && regressor.factors[j - 1] > regressor.factors[j]; --j) {
      std::swap(regressor.factors[j - 1], regressor.factors[j]);
    }
  }
  return regressor;
}

}  // namespace imucal::core

#endif  // IMUCAL_CORE_REGRESSOR_H_
