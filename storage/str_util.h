// String building for storage/*.cc: core's (see core/str_util.h for why it exists).
#ifndef IMUCAL_STORAGE_STR_UTIL_H_
#define IMUCAL_STORAGE_STR_UTIL_H_

#include "core/str_util.h"

namespace imucal::storage {
using core::AppendPiece;
using core::AppendTo;
using core::Cat;
}  // namespace imucal::storage

#endif  // IMUCAL_STORAGE_STR_UTIL_H_
