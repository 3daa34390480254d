// The JSON the reports write (summary, profile, scale, modes, the output's layout), built as
// nlohmann-json values: the library escapes strings and prints numbers.
#pragma once

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <string>

#include <nlohmann/json.hpp>

namespace cvt {

// Keys keep the order they are written in.
using Json = nlohmann::ordered_json;

// x as a JSON number (null when not finite), rounded to `digits` significant digits: the
// value a reader of printf's "%.<digits>g" gets (17 digits keep every bit).
inline Json json_number(double x, int digits = 17) {
  if (!std::isfinite(x)) return nullptr;
  if (digits >= 17) return x;
  char b[40];
  std::snprintf(b, sizeof b, "%.*g", digits, x);
  return std::strtod(b, nullptr);
}

// A report file's text: indented by two, UTF-8 kept as it is (bytes that are not UTF-8
// become U+FFFD), a newline at the end.
inline std::string json_text(const Json& j) {
  return j.dump(2, ' ', false, Json::error_handler_t::replace) + "\n";
}

// j on one line with ", " and ": " between items and numbers printed as "%.17g": the form of
// the layout attribute in /parameters (docs/output.md), whose bytes stay as they are.
inline std::string json_inline(const Json& j) {
  switch (j.type()) {
    case Json::value_t::object: {
      std::string o = "{";
      for (auto it = j.begin(); it != j.end(); ++it) {
        if (it != j.begin()) o += ", ";
        o += Json(it.key()).dump() + ": " + json_inline(it.value());
      }
      return o + "}";
    }
    case Json::value_t::array: {
      std::string o = "[";
      for (std::size_t i = 0; i < j.size(); ++i) o += (i ? ", " : "") + json_inline(j[i]);
      return o + "]";
    }
    case Json::value_t::number_float: {
      char b[32];
      std::snprintf(b, sizeof b, "%.17g", j.get<double>());
      return b;
    }
    default:
      return j.dump(-1, ' ', false, Json::error_handler_t::replace);
  }
}

}  // namespace cvt
