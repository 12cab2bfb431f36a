// Early-return helpers for absl::Status / absl::StatusOr, private to storage/*.cc.
#ifndef IMUCAL_STORAGE_STATUS_MACROS_H_
#define IMUCAL_STORAGE_STATUS_MACROS_H_

#include <utility>

#include "absl/status/status.h"
#include "absl/status/statusor.h"

#define STORAGE_RETURN_IF_ERROR(expr)                                   \
  do {                                                                  \
    if (absl::Status storage_status_ = (expr); !storage_status_.ok()) { \
      return storage_status_;                                           \
    }                                                                   \
  } while (false)

#define STORAGE_CONCAT_INNER_(a, b) a##b
#define STORAGE_CONCAT_(a, b) STORAGE_CONCAT_INNER_(a, b)

// STORAGE_ASSIGN_OR_RETURN(auto x, F()); or STORAGE_ASSIGN_OR_RETURN(x, F());
#define STORAGE_ASSIGN_OR_RETURN(lhs, expr) \
  STORAGE_ASSIGN_OR_RETURN_IMPL_(STORAGE_CONCAT_(storage_statusor_, __LINE__), lhs, expr)
#define STORAGE_ASSIGN_OR_RETURN_IMPL_(tmp, lhs, expr) \
  auto tmp = (expr);                                   \
  if (!tmp.ok()) return tmp.status();                  \
  lhs = std::move(*tmp)

#endif  // IMUCAL_STORAGE_STATUS_MACROS_H_
