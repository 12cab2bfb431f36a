// Boost.Math's distributions as core uses them: they report an argument out of a distribution's
// domain, a root their quantile search cannot bracket, or an overflow by throwing. Core throws
// nothing, and an exception out of a solve would end the server's process, so every call goes
// through MathOr, which gives a fallback instead (callers pass infinity: "nothing is detectable
// here"). Boost.Math's ignore_error policies are no substitute: some of its quantiles then read
// an uninitialised value on the error path.
#ifndef IMUCAL_CORE_MATH_GUARD_H_
#define IMUCAL_CORE_MATH_GUARD_H_

#include <cmath>
#include <exception>

namespace imucal::core {

// fn() (a Boost.Math computation giving a double), or `fallback` when it throws or gives NaN.
template <typename Fn>
double MathOr(double fallback, const Fn& fn) noexcept {
  try {
    const double value = fn();
    return std::isnan(value) ? fallback : value;
  } catch (const std::exception&) {
    return fallback;
  }
}

}  // namespace imucal::core

#endif  // IMUCAL_CORE_MATH_GUARD_H_
