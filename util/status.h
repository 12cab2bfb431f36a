// Early returns for absl::Status and absl::StatusOr, for every imucal library.
//   IMUCAL_RETURN_IF_ERROR(DoIt());            returns DoIt()'s status when it is not OK
//   IMUCAL_ASSIGN_OR_RETURN(auto x, Make());   x = *Make(), or returns Make()'s status
#ifndef IMUCAL_UTIL_STATUS_H_
#define IMUCAL_UTIL_STATUS_H_

#include <utility>

#include "absl/status/status.h"
#include "absl/status/statusor.h"

#define IMUCAL_RETURN_IF_ERROR(expr)                                  \
  do {                                                                \
    if (absl::Status imucal_status_ = (expr); !imucal_status_.ok()) { \
      return imucal_status_;                                          \
    }                                                                 \
  } while (false)

#define IMUCAL_STATUS_CONCAT_INNER_(a, b) a##b
#define IMUCAL_STATUS_CONCAT_(a, b) IMUCAL_STATUS_CONCAT_INNER_(a, b)

// IMUCAL_ASSIGN_OR_RETURN(auto x, F()); or IMUCAL_ASSIGN_OR_RETURN(x, F());
#define IMUCAL_ASSIGN_OR_RETURN(lhs, expr) \
  IMUCAL_ASSIGN_OR_RETURN_IMPL_(IMUCAL_STATUS_CONCAT_(imucal_statusor_, __LINE__), lhs, expr)
#define IMUCAL_ASSIGN_OR_RETURN_IMPL_(tmp, lhs, expr) \
  auto tmp = (expr);                                  \
  if (!tmp.ok()) return tmp.status();                 \
  lhs = std::move(*tmp)

#endif  // IMUCAL_UTIL_STATUS_H_
