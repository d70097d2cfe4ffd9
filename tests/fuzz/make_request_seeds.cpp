// Writes the seed corpus of fuzz_request: one valid request of each kind, prefixed by the byte
// that selects its kind (see fuzz_request.cpp). Run once from the fuzz build and commit the
// output (tests/fuzz/corpus/fuzz_request/).
//
//   build-fuzz/tests/fuzz/meshdeform_fuzz_request_seeds tests/fuzz/corpus/fuzz_request
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>

#include "meshdeform/v1/deformation.pb.h"

namespace fs = std::filesystem;
using namespace meshdeform;

namespace {

void put(const fs::path& dir, const std::string& name, char kind,
         const google::protobuf::Message& message) {
  fs::create_directories(dir);
  std::ofstream out(dir / name, std::ios::binary);
  out << kind << message.SerializeAsString();
}

}  // namespace

int main(int argc, char** argv) {
  if (argc != 2) {
    std::fprintf(stderr, "usage: %s OUT_DIR\n", argv[0]);
    return 2;
  }
  const fs::path dir = argv[1];
  // cylinder_small: 420 vertices, the first and last rings (20 each) fixed / handle.
  v1::SetHandlesRequest handles;
  v1::HandleGroup* fixed = handles.add_groups();
  fixed->set_role(v1::HANDLE_ROLE_FIXED);
  v1::HandleGroup* handle = handles.add_groups();
  handle->set_role(v1::HANDLE_ROLE_HANDLE);
  for (unsigned v = 0; v < 20; ++v) {
    fixed->add_vertices(v);
    handle->add_vertices(400 + v);
  }
  put(dir, "set_handles", '\0', handles);

  v1::MoveHandlesRequest move;
  v1::GroupMove* g = move.add_moves();
  g->set_group(1);
  g->mutable_translation()->set_x(0.2);
  g->mutable_rotation()->set_w(0.96);
  g->mutable_rotation()->set_y(0.28);
  g->set_scale(1.1);
  move.set_max_iterations(2);
  put(dir, "move_group", '\1', move);
  move.set_encoding(v1::POSITION_ENCODING_MESHOPT);
  v1::MagnifyRegion* region = move.add_magnify();
  for (unsigned v = 200; v < 260; ++v) region->add_vertices(v);
  region->set_scale(1.5);
  put(dir, "move_magnify_meshopt", '\1', move);
  v1::MoveHandlesRequest targets;
  targets.set_method(v1::METHOD_ARAP);
  targets.set_encoding(v1::POSITION_ENCODING_FLOAT32);
  targets.mutable_targets()->add_vertices(405);
  for (double x : {0.1, 0.2, 1.3}) targets.mutable_targets()->add_positions(x);
  put(dir, "move_targets_arap", '\1', targets);

  v1::CreateSessionRequest sample;
  sample.set_sample("bar_small");
  put(dir, "create_sample", '\2', sample);
  v1::CreateSessionRequest obj;
  obj.set_mesh_bytes("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n");
  obj.set_format(v1::MESH_FORMAT_OBJ);
  obj.set_lambda(50);
  put(dir, "create_obj", '\2', obj);
  return 0;
}
