// libFuzzer target: the request-decoding layer. The first byte picks a message (SetHandles,
// MoveHandles, CreateSession, or a position encoding), the rest is parsed as its wire bytes
// (protobuf), converted by proto_convert and executed against a real DeformationService holding a
// small cylinder with handles — the path every gRPC and gRPC-Web request takes after the
// transport. Each input must be rejected with a documented status or executed; results are
// encoded back in the requested encoding. Session ids and tokens are replaced by the real ones
// (a fuzzer cannot guess 256-bit tokens; token checks are tested elsewhere), and iteration
// budgets are capped at 2 so that one input stays fast.
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <memory>
#include <string>
#include <vector>

#include <meshoptimizer.h>

#include "meshdeform/v1/deformation.pb.h"
#include "server/service/deformation_service.h"
#include "server/transport/proto_convert.h"
#include "tests/fuzz/fuzz_support.h"

using namespace meshdeform;

namespace {

struct Fixture {
  std::unique_ptr<service::DeformationService> service;
  service::CreatedSession session;
};

Fixture& fixture() {
  static Fixture* f = [] {
    auto* out = new Fixture;
    service::ServiceOptions options;
    options.workers = 1;
    options.max_vertices = 5'000;
    options.max_sessions = 8;
    options.create_rate = {0, 1};
    options.move_rate = {0, 1};
    out->service = std::make_unique<service::DeformationService>(options);
    service::CreateSessionRequest request;
    request.sample = "cylinder_small";
    Result<service::CreatedSession> created = out->service->create_session(request);
    fuzz::fuzz_check(created.ok(), "fixture session");
    out->session = *created;
    fuzz::fuzz_check(out->service
                         ->set_handles(out->session.id, out->session.edit_token,
                                       {out->session.suggested_groups})
                         .ok(),
                     "fixture handles");
    return out;
  }();
  return *f;
}

/// Restores the fixture's handles after an input changed them, so that moves keep being tried.
void reset_handles(Fixture& f) {
  fuzz::fuzz_check(
      f.service->set_handles(f.session.id, f.session.edit_token, {f.session.suggested_groups}).ok(),
      "restoring the fixture's handles");
}

/// Decodes packed float32 rows (FLOAT32 or MESHOPT) and checks that they are exactly the float
/// rounding of `rows`.
void check_packed(const std::string& bytes, v1::PositionEncoding encoding, const Positions& rows) {
  const std::size_t count = static_cast<std::size_t>(rows.rows());
  if (count == 0) {
    fuzz::fuzz_check(bytes.empty(), "bytes for no vertex");
    return;
  }
  std::vector<float> decoded(3 * count);
  if (encoding == v1::POSITION_ENCODING_FLOAT32) {
    fuzz::fuzz_check(bytes.size() == decoded.size() * sizeof(float), "float32 size");
    std::memcpy(decoded.data(), bytes.data(), bytes.size());
  } else {
    fuzz::fuzz_check(meshopt_decodeVertexBuffer(decoded.data(), count, 3 * sizeof(float),
                                                reinterpret_cast<const unsigned char*>(bytes.data()),
                                                bytes.size()) == 0,
                     "meshopt bytes do not decode");
  }
  for (std::size_t r = 0; r < count; ++r) {
    for (int c = 0; c < 3; ++c) {
      fuzz::fuzz_check(decoded[3 * r + c] == static_cast<float>(rows(static_cast<Eigen::Index>(r), c)),
                       "packed positions differ from the float rounding of the result");
    }
  }
}

void check_result(const service::DeformResult& result, v1::PositionEncoding encoding) {
  fuzz::fuzz_check(result.positions && result.positions->allFinite(), "non-finite result");
  v1::DeformResult wire;
  transport::result_to_proto(result, false, encoding, &wire);
  if (encoding == v1::POSITION_ENCODING_UNSPECIFIED) {
    fuzz::fuzz_check(!wire.dense(), "doubles sent dense");
    fuzz::fuzz_check(wire.changed_indices_size() == static_cast<int>(result.changed.size()) &&
                         wire.changed_positions_size() == 3 * wire.changed_indices_size(),
                     "changed lists lost in encoding");
    return;
  }
  if (wire.dense()) {
    // Dense: every position, no indices.
    fuzz::fuzz_check(wire.changed_indices_size() == 0, "dense delta with indices");
    check_packed(wire.packed_positions(), encoding, *result.positions);
  } else {
    fuzz::fuzz_check(wire.changed_indices_size() == static_cast<int>(result.changed.size()),
                     "changed indices lost in encoding");
    check_packed(wire.packed_changed_positions(), encoding, result.changed_positions);
  }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size < 1) return 0;
  Fixture& f = fixture();
  const std::uint8_t kind = data[0] % 3;
  const void* body = data + 1;
  const int body_size = static_cast<int>(size - 1);
  switch (kind) {
    case 0: {
      v1::SetHandlesRequest request;
      if (!request.ParseFromArray(body, body_size)) return 0;
      Result<service::SetHandlesRequest> converted = transport::set_handles_from_proto(request);
      if (!converted.ok()) {
        fuzz::check_error(converted.status());
        return 0;
      }
      Result<service::SessionInfo> info =
          f.service->set_handles(f.session.id, f.session.edit_token, *converted);
      if (!info.ok()) {
        fuzz::check_error(info.status());
      } else {
        reset_handles(f);
      }
      return 0;
    }
    case 1: {
      v1::MoveHandlesRequest request;
      if (!request.ParseFromArray(body, body_size)) return 0;
      Result<v1::PositionEncoding> encoding = transport::encoding_from_proto(request.encoding());
      Result<service::MoveRequest> converted = transport::move_from_proto(request);
      if (!encoding.ok() || !converted.ok()) {
        fuzz::check_error(!encoding.ok() ? encoding.status() : converted.status());
        return 0;
      }
      converted->max_iterations = std::min(converted->max_iterations, 2);
      Result<service::DeformResult> result =
          f.service->move_handles(f.session.id, f.session.edit_token, *converted);
      if (!result.ok()) {
        fuzz::check_error(result.status());
        return 0;
      }
      check_result(*result, *encoding);
      return 0;
    }
    default: {
      v1::CreateSessionRequest request;
      if (!request.ParseFromArray(body, body_size)) return 0;
      Result<service::CreateSessionRequest> converted = transport::create_request_from_proto(request);
      if (!converted.ok()) {
        fuzz::check_error(converted.status());
        return 0;
      }
      Result<service::CreatedSession> created = f.service->create_session(*converted);
      if (!created.ok()) {
        fuzz::check_error(created.status());
        return 0;
      }
      fuzz::fuzz_check(f.service->close_session(created->id, created->edit_token).ok(),
                       "closing a created session");
      return 0;
    }
  }
}
