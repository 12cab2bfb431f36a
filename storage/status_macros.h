// Context helpers for absl::Status / absl::StatusOr, private to storage/*.cc (the early returns
// are util/status.h's).
#ifndef IMUCAL_STORAGE_STATUS_MACROS_H_
#define IMUCAL_STORAGE_STATUS_MACROS_H_

#include <string_view>
#include <utility>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "storage/types.h"
#include "util/status.h"  // IMUCAL_RETURN_IF_ERROR, IMUCAL_ASSIGN_OR_RETURN
#include "util/str_util.h"

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
