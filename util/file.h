// Files read and written whole, for every imucal library: one way to read a file, and one
// durable atomic write (the file is complete under its name or not there at all, and stays so
// across a crash or a power cut). Errors name the path and keep errno's code (NotFound,
// PermissionDenied, ...).
#ifndef IMUCAL_UTIL_FILE_H_
#define IMUCAL_UTIL_FILE_H_

#include <cstddef>
#include <optional>
#include <string>
#include <string_view>

#include "absl/status/status.h"
#include "absl/status/statusor.h"

namespace imucal {

// The whole file, or at most `max_bytes` of it. A directory is InvalidArgument.
absl::StatusOr<std::string> ReadFileBytes(const std::string& path,
                                          std::optional<size_t> max_bytes = std::nullopt);

// Replaces `path` with `data`, atomically and durably: writes `path`.tmp.<pid> beside it, syncs
// it, renames it over `path` and syncs the directory. On an error `path` is as it was and the
// temporary file is gone.
absl::Status WriteFileDurably(const std::string& path, std::string_view data);

// fsync of a file, or of a directory (making a rename in it durable).
absl::Status FsyncPath(const std::string& path, bool directory);

// The directory holding `path` ("." for a bare name).
std::string DirectoryOf(const std::string& path);

}  // namespace imucal

#endif  // IMUCAL_UTIL_FILE_H_
