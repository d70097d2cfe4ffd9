// The web viewer's decoder (web_viewer/src/update_codec.ts) is tested on updates this encoder
// made: web_viewer/test/fixtures/update_stream.json. This test checks that the committed fixture
// still decodes here to the positions it states (so the two decoders read one format), and
// rewrites it from the encoder when MESHDEFORM_WRITE_VIEWER_FIXTURE=1 is set (after a format
// change; the vitest test then checks the viewer against it).
#include <gtest/gtest.h>

#include <nlohmann/json.hpp>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <sstream>
#include <string>

#include "codec/update_codec.h"

namespace meshdeform::codec {
namespace {

using Json = nlohmann::json;

const char kAlphabet[] = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";

std::string base64(const std::string& bytes) {
  std::string out;
  std::size_t i = 0;
  for (; i + 2 < bytes.size(); i += 3) {
    const unsigned v = (static_cast<unsigned char>(bytes[i]) << 16) |
                       (static_cast<unsigned char>(bytes[i + 1]) << 8) |
                       static_cast<unsigned char>(bytes[i + 2]);
    for (int k = 18; k >= 0; k -= 6) out += kAlphabet[(v >> k) & 63];
  }
  if (i < bytes.size()) {
    unsigned v = static_cast<unsigned char>(bytes[i]) << 16;
    if (i + 1 < bytes.size()) v |= static_cast<unsigned char>(bytes[i + 1]) << 8;
    out += kAlphabet[(v >> 18) & 63];
    out += kAlphabet[(v >> 12) & 63];
    out += i + 1 < bytes.size() ? kAlphabet[(v >> 6) & 63] : '=';
    out += '=';
  }
  return out;
}

std::string unbase64(const std::string& text) {
  std::string out;
  unsigned v = 0;
  int bits = 0;
  for (char c : text) {
    const char* at = std::strchr(kAlphabet, c);
    if (c == '=' || at == nullptr || c == '\0') continue;
    v = (v << 6) | static_cast<unsigned>(at - kAlphabet);
    bits += 6;
    if (bits >= 8) {
      bits -= 8;
      out += static_cast<char>((v >> bits) & 0xff);
    }
  }
  return out;
}

/// A wavy strip of `n` vertices and a few revisions of it; `noisy` adds a deterministic jitter
/// that does not compress (so a small budget binds).
Positions pose(int revision, int n, bool noisy) {
  Positions out(n, 3);
  std::uint32_t x32 = 7u + static_cast<std::uint32_t>(revision);
  for (int i = 0; i < n; ++i) {
    const double x = i / static_cast<double>(n - 1);
    out.row(i) << x, 0.1 * (i % 2), 0.02 * std::sin(5 * x) + 0.05 * revision * x * x;
    if (noisy) {
      x32 = x32 * 1664525u + 1013904223u;
      out(i, 2) += 1e-3 * static_cast<double>(x32 >> 8) / 16777216.0;
    }
  }
  if (revision == 3) out(5, 1) = -0.0;
  return out;
}

/// `lossless_revision` >= 0: that revision goes lossless in a quantized stream (a settled one,
/// UpdateOptions.lossless_settled).
Json stream_json(DeltaMode mode, std::size_t budget, int n = 64, double tolerance = 1e-3,
                 int lossless_revision = -1) {
  const bool noisy = budget > 0;
  StreamSettings settings;
  settings.mode = mode;
  settings.tolerance = tolerance;
  settings.origin = Eigen::Vector3d(0, 0, -0.05);
  settings.max_update_bytes = budget;
  auto encoder = StreamEncoder::create(settings, n);
  EXPECT_TRUE(encoder.ok());
  Json updates = Json::array();
  auto add = [&](const EncodedUpdate& u) {
    const UpdateHeader& h = u.header;
    Json positions = Json::array();
    // The expected positions: what the encoder says the client holds.
    const Positions client = encoder->client_positions();
    for (int v = 0; v < n; ++v) {
      for (int c = 0; c < 3; ++c) positions.push_back(client(v, c));
    }
    updates.push_back(Json{{"mode", h.mode == DeltaMode::Quantized ? 1 : 2},
                           {"sequence", h.sequence},
                           {"revision", h.revision},
                           {"vertexCount", h.vertex_count},
                           {"verticesSent", h.vertices_sent},
                           {"step", h.step},
                           {"origin", {h.origin.x(), h.origin.y(), h.origin.z()}},
                           {"shift", h.shift},
                           {"maxError", h.max_error},
                           {"pendingVertices", h.pending_vertices},
                           {"payload", base64(u.payload)},
                           {"positions", positions}});
  };
  for (int r = 0; r < 4; ++r) {
    auto u = encoder->encode(pose(r, n, noisy), static_cast<std::uint64_t>(r), r == lossless_revision);
    EXPECT_TRUE(u.ok());
    add(*u);
    for (int i = 0; i < 20 && encoder->pending(); ++i) {
      auto more = encoder->encode_pending();
      EXPECT_TRUE(more.ok());
      add(*more);
    }
  }
  return updates;
}

TEST(ViewerFixture, TheCommittedFixtureDecodesHereToItsPositions) {
  const std::string path = MESHDEFORM_VIEWER_FIXTURE;
  if (const char* write = std::getenv("MESHDEFORM_WRITE_VIEWER_FIXTURE"); write && *write == '1') {
    const Json fixture{{"note", "made by tests/codec/viewer_fixture_test.cpp (codec/update_codec.h)"},
                       {"quantized", stream_json(DeltaMode::Quantized, 0)},
                       {"budgeted", stream_json(DeltaMode::Quantized, 1024, 400, 1e-9)},
                       {"lossless", stream_json(DeltaMode::Lossless, 0)},
                       {"settled", stream_json(DeltaMode::Quantized, 0, 64, 1e-3, 2)}};
    std::ofstream(path) << fixture.dump() << "\n";
  }
  std::ifstream in(path);
  ASSERT_TRUE(in) << "missing " << path;
  const Json fixture = Json::parse(in);
  int decoded = 0;
  for (const char* name : {"quantized", "budgeted", "lossless", "settled"}) {
    StreamDecoder decoder;
    for (const Json& u : fixture.at(name)) {
      UpdateHeader h;
      h.mode = u.at("mode").get<int>() == 1 ? DeltaMode::Quantized : DeltaMode::Lossless;
      h.sequence = u.at("sequence");
      h.revision = u.at("revision");
      h.vertex_count = u.at("vertexCount");
      h.vertices_sent = u.at("verticesSent");
      h.step = u.at("step");
      h.origin = Eigen::Vector3d(u.at("origin")[0], u.at("origin")[1], u.at("origin")[2]);
      h.shift = u.at("shift");
      h.max_error = u.at("maxError");
      h.pending_vertices = u.at("pendingVertices");
      ASSERT_TRUE(decoder.apply(h, unbase64(u.at("payload"))).ok()) << name << " " << h.sequence;
      const Json& expected = u.at("positions");
      ASSERT_EQ(expected.size(), 3u * h.vertex_count);
      for (int v = 0; v < static_cast<int>(h.vertex_count); ++v) {
        for (int c = 0; c < 3; ++c) {
          const double want = expected[static_cast<std::size_t>(3 * v + c)];
          EXPECT_EQ(decoder.positions()(v, c), want) << name << " update " << h.sequence;
        }
      }
      ++decoded;
    }
  }
  EXPECT_GE(decoded, 10);
}

}  // namespace
}  // namespace meshdeform::codec
