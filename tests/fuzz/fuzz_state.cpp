// libFuzzer target: session state files (server/service/persistence.h), which a replica reads
// from a shared state directory and which hold the edit state of issue 17. The input is a
// payload; the target frames it as a file (magic, length, CRC-32) so that the fuzzer explores
// the fields instead of the checksum. Every input must be refused with InvalidArgument or decode
// to a state that encodes and decodes again to the same bytes.
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <string>
#include <string_view>

#include "server/service/persistence.h"

using namespace meshdeform;

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string_view payload(reinterpret_cast<const char*>(data), size);
  std::string file = "MDSTATE1";
  const std::uint64_t length = size;
  file.append(reinterpret_cast<const char*>(&length), sizeof(length));
  file.append(payload);
  const std::uint32_t crc = service::state_checksum(payload);
  file.append(reinterpret_cast<const char*>(&crc), sizeof(crc));

  Result<service::PersistedSession> decoded = service::decode_session(file);
  if (!decoded.ok()) {
    if (decoded.status().code() != ErrorCode::InvalidArgument) std::abort();
    return 0;
  }
  const std::string again = service::encode_session(*decoded);
  Result<service::PersistedSession> back = service::decode_session(again);
  if (!back.ok() || service::encode_session(*back) != again) std::abort();
  return 0;
}
