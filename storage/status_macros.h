// Early-return and context helpers for absl::Status / absl::StatusOr, private to storage/*.cc.
#ifndef IMUCAL_STORAGE_STATUS_MACROS_H_
#define IMUCAL_STORAGE_STATUS_MACROS_H_

#include <string_view>
#include <utility>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "storage/types.h"
#include "util/str_util.h"

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

namespace imucal::storage {

// Errors name what they come from (a call, a file): "<op>: <message>", the prefix also kept as
// kOperationPayload (types.h), by which the server takes it off before a client sees it.
inline absl::Status WithContext(std::string_view op, const absl::Status& s) {
  return WithOperation(op, s);
}
// `result` unchanged when it is OK, else with `op` as WithContext adds it.
template <typename T>
absl::StatusOr<T> Annotate(std::string_view op, absl::StatusOr<T> result) {
  if (!result.ok()) return WithContext(op, result.status());
  return result;
}
inline absl::Status Annotate(std::string_view op, absl::Status result) {
  if (!result.ok()) return WithContext(op, result);
  return result;
}

}  // namespace imucal::storage

#endif  // IMUCAL_STORAGE_STATUS_MACROS_H_
