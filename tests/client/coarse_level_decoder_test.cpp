// The client's decoding of a Watch stream's coarse levels (WatchOptions::coarse_preview): the
// server sends a level's mesh once per stream and positions only after that; a response that
// breaks the protocol is a malformed response, never a crash or a silently wrong level.
#include <gtest/gtest.h>

#include <cstring>
#include <string>
#include <vector>

#include "client_cpp/client_conversions.h"

namespace meshdeform::client::detail {
namespace {

// A level of two triangles on four vertices (fine vertices 0, 5, 9, 12) at `shift` along x.
v1::CoarseLevel level(std::uint64_t key, float shift, bool with_mesh) {
  v1::CoarseLevel out;
  out.set_key(key);
  out.set_vertex_count(4);
  const std::vector<float> xyz = {shift, 0, 0, shift + 1, 0, 0, shift, 1, 0, shift + 1, 1, 0};
  out.set_positions(std::string(reinterpret_cast<const char*>(xyz.data()), xyz.size() * 4));
  if (with_mesh) {
    for (const std::uint32_t t : {0u, 1u, 2u, 2u, 1u, 3u}) out.add_triangles(t);
    for (const std::uint32_t v : {0u, 5u, 9u, 12u}) out.add_to_fine(v);
  }
  return out;
}

TEST(CoarseLevelDecoder, FillsInTheMeshSentWithTheLevelsFirstUpdate) {
  CoarseLevelDecoder decoder;
  const Result<CoarseLevel> first = decoder.decode(level(7, 0.0f, true));
  ASSERT_TRUE(first.ok()) << first.status().to_string();
  const Result<CoarseLevel> later = decoder.decode(level(7, 2.5f, false));
  ASSERT_TRUE(later.ok()) << later.status().to_string();
  EXPECT_EQ(later->key, 7u);
  EXPECT_EQ(later->triangles, first->triangles);
  EXPECT_EQ(later->to_fine, (std::vector<int>{0, 5, 9, 12}));
  ASSERT_EQ(later->positions.rows(), 4);
  EXPECT_EQ(later->positions(3, 0), 3.5);
  EXPECT_EQ(later->positions(3, 1), 1.0);
  EXPECT_EQ(later->triangles(1, 2), 3);
}

TEST(CoarseLevelDecoder, AProtocolBreachIsAMalformedResponse) {
  const auto rejected = [](const v1::CoarseLevel& in, CoarseLevelDecoder decoder = {}) {
    const Result<CoarseLevel> r = decoder.decode(in);
    EXPECT_FALSE(r.ok());
    if (r.ok()) return std::string();
    EXPECT_EQ(r.status().code(), ErrorCode::InvalidArgument);
    EXPECT_NE(r.status().message().find("Watch: malformed response: coarse level"),
              std::string::npos)
        << r.status().message();
    return r.status().message();
  };
  // Positions before the level's mesh ever came.
  EXPECT_NE(rejected(level(7, 0.0f, false)).find("never came"), std::string::npos);
  // Positions of the wrong size.
  v1::CoarseLevel short_positions = level(7, 0.0f, true);
  short_positions.mutable_positions()->resize(40);
  rejected(short_positions);
  // A triangle index past the level's vertices.
  v1::CoarseLevel bad_triangle = level(7, 0.0f, true);
  bad_triangle.set_triangles(5, 4);
  EXPECT_NE(rejected(bad_triangle).find("triangle index 4"), std::string::npos);
  // to_fine not one per vertex; triangles not in threes.
  v1::CoarseLevel short_map = level(7, 0.0f, true);
  short_map.mutable_to_fine()->RemoveLast();
  rejected(short_map);
  v1::CoarseLevel loose_triangles = level(7, 0.0f, true);
  loose_triangles.add_triangles(0);
  rejected(loose_triangles);
  // A known key whose update claims another vertex count.
  CoarseLevelDecoder decoder;
  ASSERT_TRUE(decoder.decode(level(7, 0.0f, true)).ok());
  v1::CoarseLevel grown = level(7, 0.0f, false);
  grown.set_vertex_count(5);
  grown.mutable_positions()->resize(60);
  rejected(grown, decoder);
}

}  // namespace
}  // namespace meshdeform::client::detail
