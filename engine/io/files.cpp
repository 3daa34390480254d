#include "engine/io/files.hpp"

#include <fcntl.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <stdexcept>

namespace cvt {

void replace_file(const std::string& path, const void* bytes, std::size_t size) {
  const std::string tmp = path + ".tmp";
  const auto fail = [&](const char* doing, int err) {
    ::unlink(tmp.c_str());
    throw std::runtime_error(std::string("cannot ") + doing + " '" + path + "': " + std::strerror(err) +
                      " (the file is left as it was)");
  };
  const int fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd < 0) fail("write", errno);
  const char* p = static_cast<const char*>(bytes);
  for (std::size_t left = size; left > 0;) {
    const ssize_t n = ::write(fd, p, left);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) {
      const int err = n < 0 ? errno : ENOSPC;
      ::close(fd);
      fail("write", err);
    }
    p += n, left -= static_cast<std::size_t>(n);
  }
  if (::fsync(fd) != 0) {
    const int err = errno;
    ::close(fd);
    fail("write", err);
  }
  if (::close(fd) != 0) fail("write", errno);
  if (::rename(tmp.c_str(), path.c_str()) != 0) fail("replace", errno);
}

}  // namespace cvt
