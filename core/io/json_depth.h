#pragma once
/// @file json_depth.h
/// Nesting depth of JSON text, measured before any JSON parser sees it: JSON tree walks recurse
/// (tinygltf's value conversion, our finiteness check), so hostile nesting must be refused first.
/// Internal to meshdeform::io.

#include <cstddef>
#include <string_view>

namespace meshdeform::io {

/// The deepest nesting of arrays and objects in `text`, skipping string contents and escapes;
/// stops scanning once `limit` is exceeded (returns limit + 1). O(bytes), no allocation. The text
/// need not be valid JSON: the parser reports syntax errors afterwards.
inline int json_nesting_depth(std::string_view text, int limit) {
  int depth = 0;
  int deepest = 0;
  bool in_string = false;
  bool escaped = false;
  for (const char c : text) {
    if (in_string) {
      if (escaped) {
        escaped = false;
      } else if (c == '\\') {
        escaped = true;
      } else if (c == '"') {
        in_string = false;
      }
      continue;
    }
    if (c == '"') {
      in_string = true;
    } else if (c == '[' || c == '{') {
      if (++depth > deepest) {
        deepest = depth;
        if (deepest > limit) return limit + 1;
      }
    } else if ((c == ']' || c == '}') && depth > 0) {
      --depth;
    }
  }
  return deepest;
}

}  // namespace meshdeform::io
