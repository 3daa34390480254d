// Files written whole or not at all.
#pragma once

#include <cstddef>
#include <string>

namespace cvt {

// Replaces path with the bytes, all or nothing: written to PATH.tmp, synced to the disk and
// renamed over path. A write error (a full disk) removes PATH.tmp, leaves path as it was
// and throws std::runtime_error naming the path and the system's reason.
void replace_file(const std::string& path, const void* bytes, std::size_t size);

}  // namespace cvt
