// Regressors of the extra error effects (report.md, "effects"): the signal an effect is
// proportional to, e.g. `temperature`, `ax*az`, `temperature^2`, `time`.
//
// Grammar (case-sensitive; spaces and tabs around a term are ignored):
//   regressor = term ('*' term)*        at most kMaxRegressorFactors factors in all
//   term      = base | base '^2'
//   base      = signal | '(' centred ('-' | '+') number ')' | '|' sensor '|'
//   signal    = temperature | time | sensor
//   sensor    = ax | ay | az | gx | gy | gz
//   centred   = temperature | time
// A centred factor `(temperature-31.2)` is the signal minus its reference (report.md,
// "effect_reference"): degC and time since power-on have no physical zero, so a polynomial in
// them is written about a reference inside the data, where its coefficients are nearly
// independent (`(temperature-31.2)^2` next to `(temperature-31.2)` is a quadratic with its
// turnover wherever the two put it). One reference per signal within a regressor. The number is
// written in the shortest form that reads back to the same double, so a name evaluates exactly
// what was fitted.
// An absolute value `|gx|` reads the magnitude of a sensor signal: `|gx|*gx` is a rate-dependent
// scale (the reading's gain grows with the rate's size, whatever its sign), `|gx|` alone a
// scale that differs between the two directions of rotation (scale-factor asymmetry). Only
// sensor signals take it: temperature and time are centred instead. Names without `|` mean what
// they always meant; a reader older than the absolute value refuses a name that has one.
// Units: temperature degC; time s from capture start; ax..az specific force m/s^2; gx..gz rate
// rad/s (calibrated values in a solve, true values in the simulator).
//
// The parsed form is the multiset of factors, sorted in signal order (a plain factor before the
// absolute value of the same signal), so `az*ax` and `ax*az` are the same regressor and Name()
// gives the canonical spelling: factors in signal order, each repeated pair written `s^2`
// (`ax*temperature*ax` -> `temperature*ax^2`, `|gx|*gx` -> `gx*|gx|`).
//
// Header-only, standard library only: the robot SDK evaluates effects per sample with it.
// Evaluate() neither allocates nor throws.
#ifndef IMUCAL_CORE_REGRESSOR_H_
#define IMUCAL_CORE_REGRESSOR_H_

#include <array>
#include <charconv>
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
  // Per factor: its absolute value `|gx|` (sensor signals only). Sorted with `factors`: among
  // factors of one signal, plain ones first. Entries at and beyond num_factors are false.
  std::array<bool, kMaxRegressorFactors> absolute = {};
  int num_factors = 0;  // 0: the constant 1 (never produced by ParseRegressor; Name() is "")
  // Per signal, the reference its factors are centred on (0: not centred). Only temperature and
  // time are ever centred; entries of signals the regressor does not use stay 0.
  SignalArray centre{};

  // Product of the factor signals, each minus its centre. `signals` indexed by Signal.
  double Evaluate(const SignalArray& signals) const {
    double value = 1.0;
    for (int i = 0; i < num_factors; ++i) {
      const auto s = static_cast<size_t>(factors[i]);
      const double v = signals[s] - centre[s];
      value *= absolute[i] && v < 0 ? -v : v;
    }
    return value;
  }

  // This regressor with its temperature and time factors centred on `reference` (indexed by
  // Signal; only the temperature and time entries are read).
  Regressor CentredOn(const SignalArray& reference) const {
    Regressor out = *this;
    out.centre = {};
    for (int i = 0; i < num_factors; ++i) {
      const auto s = static_cast<size_t>(factors[i]);
      if (IsCentrable(factors[i])) out.centre[s] = reference[s];
    }
    return out;
  }

  static bool IsCentrable(int signal) {
    return signal == static_cast<int>(Signal::kTemperature) ||
           signal == static_cast<int>(Signal::kTime);
  }

  // True when some factor is an absolute value.
  bool HasAbsolute() const {
    for (int i = 0; i < num_factors; ++i)
      if (absolute[i]) return true;
    return false;
  }

  // The canonical name; ParseRegressor(Name()) == *this.
  std::string Name() const {
    std::string name;
    int i = 0;
    while (i < num_factors) {
      const int signal = factors[i];
      const bool abs = absolute[i];
      int run = 1;
      while (i + run < num_factors && factors[i + run] == signal && absolute[i + run] == abs) ++run;
      for (int k = 0; k < run; k += 2) {
        if (!name.empty()) name += '*';
        name += abs ? "|" + std::string(kSignalNames[static_cast<size_t>(signal)]) + "|"
                    : FactorName(signal);
        if (k + 1 < run) name += "^2";
      }
      i += run;
    }
    return name;
  }

  friend bool operator==(const Regressor&, const Regressor&) = default;

 private:
  // `temperature`, or `(temperature-31.2)` when centred.
  std::string FactorName(int signal) const {
    const std::string_view base = kSignalNames[static_cast<size_t>(signal)];
    const double c = centre[static_cast<size_t>(signal)];
    if (c == 0.0) return std::string(base);
    std::array<char, 32> digits{};
    const std::to_chars_result r =
        std::to_chars(digits.data(), digits.data() + digits.size(), c < 0 ? -c : c);
    return "(" + std::string(base) + (c < 0 ? "+" : "-") +
           std::string(digits.data(), static_cast<size_t>(r.ptr - digits.data())) + ")";
  }
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

// `(temperature-31.2)` -> (signal, centre); nullopt when `term` is not a well-formed centred
// factor of a centrable signal.
inline std::optional<std::pair<int, double>> CentredFactor(std::string_view term) {
  if (term.size() < 5 || term.front() != '(' || term.back() != ')') return std::nullopt;
  term = term.substr(1, term.size() - 2);
  const size_t sign = term.find_first_of("+-");
  if (sign == std::string_view::npos) return std::nullopt;
  const std::optional<int> signal = SignalIndex(Trim(term.substr(0, sign)));
  if (!signal.has_value() || !Regressor::IsCentrable(*signal)) return std::nullopt;
  const std::string_view number = Trim(term.substr(sign + 1));
  double value = 0;
  const std::from_chars_result r =
      std::from_chars(number.data(), number.data() + number.size(), value);
  if (r.ec != std::errc() || r.ptr != number.data() + number.size() || !(value == value) ||
      value - value != 0) {  // NaN or infinite
    return std::nullopt;
  }
  return std::make_pair(*signal, term[sign] == '-' ? value : -value);
}

}  // namespace regressor_internal

// Parses a regressor name (grammar above). nullopt for anything else: an unknown signal, an
// empty term (`ax**az`, `ax*`), another power (`ax^3`), more than kMaxRegressorFactors factors,
// a centred sensor signal (`(ax-1)`), one signal with two references
// (`temperature*(temperature-30)`), the absolute value of temperature or time (`|time|`).
inline std::optional<Regressor> ParseRegressor(std::string_view text) {
  Regressor regressor;
  std::array<bool, kNumSignals> seen{};
  while (true) {
    const size_t star = text.find('*');
    std::string_view term = regressor_internal::Trim(text.substr(0, star));
    int power = 1;
    if (term.size() >= 2 && term.substr(term.size() - 2) == "^2") {
      power = 2;
      term = regressor_internal::Trim(term.substr(0, term.size() - 2));
    }
    std::optional<int> signal = regressor_internal::SignalIndex(term);
    double centre = 0.0;
    bool absolute = false;
    if (!signal.has_value() && term.size() >= 3 && term.front() == '|' && term.back() == '|') {
      signal = regressor_internal::SignalIndex(term.substr(1, term.size() - 2));
      if (signal.has_value() && Regressor::IsCentrable(*signal)) return std::nullopt;
      absolute = true;
    } else if (!signal.has_value()) {
      const auto centred = regressor_internal::CentredFactor(term);
      if (centred.has_value()) signal = centred->first, centre = centred->second;
    }
    if (!signal.has_value() || regressor.num_factors + power > kMaxRegressorFactors) {
      return std::nullopt;
    }
    const auto s = static_cast<size_t>(*signal);
    if (seen[s] && regressor.centre[s] != centre) return std::nullopt;
    seen[s] = true;
    regressor.centre[s] = centre;
    for (int k = 0; k < power; ++k) {
      regressor.absolute[static_cast<size_t>(regressor.num_factors)] = absolute;
      regressor.factors[static_cast<size_t>(regressor.num_factors++)] = *signal;
    }
    if (star == std::string_view::npos) break;
    text.remove_prefix(star + 1);
  }
  // Insertion sort of at most four entries (std::sort trips GCC 12's -Warray-bounds here), by
  // signal, then plain before absolute.
  const auto after = [&](int a, int b) {
    return regressor.factors[a] > regressor.factors[b] ||
           (regressor.factors[a] == regressor.factors[b] && regressor.absolute[a] &&
            !regressor.absolute[b]);
  };
  for (int i = 1; i < regressor.num_factors; ++i) {
    for (int j = i; j > 0 && after(j - 1, j); --j) {
      std::swap(regressor.factors[j - 1], regressor.factors[j]);
      std::swap(regressor.absolute[j - 1], regressor.absolute[j]);
    }
  }
  return regressor;
}

}  // namespace imucal::core

#endif  // IMUCAL_CORE_REGRESSOR_H_
