// The JSON helpers the report writers share (profile, scale, modes, the output's layout).
#pragma once

#include <cmath>
#include <cstdio>
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

// x to 17 significant digits (it reads back to the same bits); null when not finite.
inline std::string json_number(double x) {
  if (!std::isfinite(x)) return "null";
  char b[32];
  std::snprintf(b, sizeof b, "%.17g", x);
  return b;
}

}  // namespace cvt
