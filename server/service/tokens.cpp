#include "server/service/tokens.h"

#include <random>

namespace meshdeform::service {

std::string random_hex(std::size_t bytes) {
  // std::random_device reads the kernel CSPRNG (getrandom / /dev/urandom) on Linux with
  // libstdc++; a fresh device per call keeps this thread-safe without a shared engine.
  static constexpr char kHex[] = "0123456789abcdef";
  std::random_device device;
  std::string out;
  out.reserve(2 * bytes);
  unsigned int word = 0;
  for (std::size_t i = 0; i < bytes; ++i) {
    if (i % 4 == 0) word = device();
    const unsigned int byte = word & 0xffU;
    word >>= 8;
    out.push_back(kHex[byte >> 4]);
    out.push_back(kHex[byte & 0xfU]);
  }
  return out;
}

bool constant_time_equal(std::string_view a, std::string_view b) {
  if (a.size() != b.size()) return false;
  // volatile keeps the compiler from turning the loop into an early-exit comparison.
  volatile unsigned char diff = 0;
  for (std::size_t i = 0; i < a.size(); ++i) {
    diff = static_cast<unsigned char>(diff | (static_cast<unsigned char>(a[i]) ^
                                              static_cast<unsigned char>(b[i])));
  }
  return diff == 0;
}

}  // namespace meshdeform::service
