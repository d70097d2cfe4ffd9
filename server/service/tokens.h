#pragma once
/// @file tokens.h
/// Unguessable identifiers and secrets, compared in constant time.

#include <cstddef>
#include <string>
#include <string_view>

namespace meshdeform::service {

/// `bytes` random bytes from std::random_device (the kernel's CSPRNG on Linux), as 2*bytes
/// lower-case hex digits.
std::string random_hex(std::size_t bytes);

/// Compares two secrets in time that depends only on their lengths (which are public).
bool constant_time_equal(std::string_view a, std::string_view b);

}  // namespace meshdeform::service
