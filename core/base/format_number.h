#pragma once
/// @file format_number.h
/// Internal to core: one number formatted with a printf format, for messages and SVG text.

#include <cstdio>
#include <string>

namespace meshdeform::core {

/// `value` formatted with `format` (one double conversion, e.g. "%g" or "%.2f").
inline std::string format_number(double value, const char* format) {
  char buffer[64];
  std::snprintf(buffer, sizeof(buffer), format, value);
  return buffer;
}

}  // namespace meshdeform::core
