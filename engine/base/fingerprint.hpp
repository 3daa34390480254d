// A stable fingerprint of a text: 64-bit FNV-1a in 16 hex digits, the same on every build
// and machine (the keys of study integrators' cache, a sweep row's configuration).
#pragma once

#include <cstdint>
#include <cstdio>
#include <string>

namespace cvt {

inline std::string fingerprint(const std::string& text) {
  std::uint64_t h = 14695981039346656037ull;
  for (const unsigned char c : text) h = (h ^ c) * 1099511628211ull;
  char b[17];
  std::snprintf(b, sizeof b, "%016llx", static_cast<unsigned long long>(h));
  return b;
}

}  // namespace cvt
