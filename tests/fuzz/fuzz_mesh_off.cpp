// libFuzzer target: OFF bytes -> read_mesh_from_memory -> validate / clean_mesh -> round trip.
#include <cstddef>
#include <cstdint>
#include <string_view>

#include "tests/fuzz/fuzz_support.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  meshdeform::fuzz::check_mesh_bytes(std::string_view(reinterpret_cast<const char*>(data), size),
                                     meshdeform::io::MeshFormat::Off);
  return 0;
}
