// The one JSON helper the report writers share (profile, scale, modes).
#pragma once

#include <string>

namespace cvt {

// s with '"' and '\' escaped, for use between double quotes in JSON.
inline std::string json_escape(const std::string& s) {
  std::string o;
  for (char c : s) {
    if (c == '"' || c == '\\') o += '\\';
    o += c;
  }
  return o;
}

}  // namespace cvt
