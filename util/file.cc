#include "util/file.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstdint>
#include <cstdio>
#include <filesystem>

#include "util/str_util.h"

namespace imucal {
namespace {

class ScopedFd {
 public:
  explicit ScopedFd(int fd) : fd_(fd) {}
  ScopedFd(const ScopedFd&) = delete;
  ScopedFd& operator=(const ScopedFd&) = delete;
  ~ScopedFd() {
    if (fd_ >= 0) ::close(fd_);
  }
  int get() const { return fd_; }
  // Closes now and reports the error that close() can carry for written files (e.g. NFS, quota).
  int Close() {
    const int result = ::close(fd_);
    fd_ = -1;
    return result;
  }

 private:
  int fd_;
};

}  // namespace

absl::StatusOr<std::string> ReadFileBytes(const std::string& path,
                                          std::optional<size_t> max_bytes) {
  ScopedFd fd(::open(path.c_str(), O_RDONLY | O_CLOEXEC));
  if (fd.get() < 0) return absl::ErrnoToStatus(errno, Cat(path, ": cannot open"));
  struct stat info;
  if (::fstat(fd.get(), &info) != 0) {
    return absl::ErrnoToStatus(errno, Cat(path, ": cannot stat"));
  }
  if (S_ISDIR(info.st_mode)) {
    return absl::InvalidArgumentError(Cat(path, ": is a directory, not a file"));
  }
  // st_size is exact for regular files; pipes and /proc files report 0 and are read in chunks.
  size_t capacity = info.st_size > 0 ? static_cast<size_t>(info.st_size) + 1 : 64 * 1024;
  if (max_bytes.has_value()) capacity = std::min(capacity, *max_bytes);
  std::string data(capacity, '\0');
  size_t size = 0;
  while (true) {
    if (size == data.size()) {
      if (max_bytes.has_value() && size >= *max_bytes) break;
      data.resize(max_bytes.has_value() ? std::min(2 * size, *max_bytes) : 2 * size);
    }
    const ssize_t n = ::read(fd.get(), data.data() + size, data.size() - size);
    if (n < 0) {
      if (errno == EINTR) continue;
      return absl::ErrnoToStatus(errno, Cat(path, ": cannot read"));
    }
    if (n == 0) break;
    size += static_cast<size_t>(n);
  }
  data.resize(size);
  return data;
}

namespace {

// Creates or truncates `path`, writes `data` and syncs it to disk.
absl::Status WriteFileBytes(const std::string& path, std::string_view data) {
  ScopedFd fd(::open(path.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644));
  if (fd.get() < 0) return absl::ErrnoToStatus(errno, Cat(path, ": cannot create"));
  while (!data.empty()) {
    const ssize_t n = ::write(fd.get(), data.data(), data.size());
    if (n < 0) {
      if (errno == EINTR) continue;
      return absl::ErrnoToStatus(errno, Cat(path, ": cannot write"));
    }
    data.remove_prefix(static_cast<size_t>(n));
  }
  // Flush to disk before a caller renames the file into place: otherwise a crash can leave the
  // new name on empty content.
  if (::fsync(fd.get()) != 0) {
    return absl::ErrnoToStatus(errno, Cat(path, ": cannot sync"));
  }
  if (fd.Close() != 0) return absl::ErrnoToStatus(errno, Cat(path, ": cannot close"));
  return absl::OkStatus();
}

}  // namespace

absl::Status FsyncPath(const std::string& path, bool directory) {
  ScopedFd fd(::open(path.c_str(), (directory ? O_RDONLY | O_DIRECTORY : O_RDONLY) | O_CLOEXEC));
  if (fd.get() < 0) return absl::ErrnoToStatus(errno, Cat(path, ": cannot open"));
  if (::fsync(fd.get()) != 0) return absl::ErrnoToStatus(errno, Cat(path, ": cannot sync"));
  return absl::OkStatus();
}

std::string DirectoryOf(const std::string& path) {
  const std::filesystem::path parent = std::filesystem::path(path).parent_path();
  return parent.empty() ? std::string(".") : parent.string();
}

absl::Status WriteFileDurably(const std::string& path, std::string_view data) {
  const std::string tmp = Cat(path, ".tmp.", static_cast<int64_t>(::getpid()));
  absl::Status s = WriteFileBytes(tmp, data);
  if (s.ok() && std::rename(tmp.c_str(), path.c_str()) != 0) {
    s = absl::ErrnoToStatus(errno, Cat(path, ": cannot rename ", tmp, " to it"));
  }
  if (!s.ok()) {
    std::remove(tmp.c_str());
    return s;
  }
  // Makes the rename durable: the directory entry must reach the disk too.
  return FsyncPath(DirectoryOf(path), /*directory=*/true);
}

}  // namespace imucal
