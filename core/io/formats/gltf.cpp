#include "core/io/formats/formats.h"

#include <tiny_gltf.h>

#include "core/io/json_depth.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <bit>
#include <cctype>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

namespace meshdeform::io::detail {

namespace {

// glTF 2.0 / GLB via tinygltf.

bool refuse_file_exists(const std::string& /*path*/, void* /*user*/) { return false; }
std::string keep_path(const std::string& path, void* /*user*/) { return path; }
bool refuse_read(std::vector<unsigned char>* /*out*/, std::string* err, const std::string& path,
                 void* /*user*/) {
  if (err != nullptr) *err += "external file access is disabled (uri '" + path + "')\n";
  return false;
}
bool refuse_write(std::string* err, const std::string& path,
                  const std::vector<unsigned char>& /*contents*/, void* /*user*/) {
  if (err != nullptr) *err += "file writing is disabled ('" + path + "')\n";
  return false;
}
// Images are irrelevant to the geometry; skipping them also avoids running an image decoder on
// untrusted bytes.
bool ignore_image(tinygltf::Image* /*image*/, const int /*index*/, std::string* /*err*/,
                  std::string* /*warn*/, int /*req_width*/, int /*req_height*/,
                  const unsigned char* /*bytes*/, int /*size*/, void* /*user*/) {
  return true;
}

std::size_t component_size(int component_type) {
  switch (component_type) {
    case TINYGLTF_COMPONENT_TYPE_BYTE:
    case TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE:
      return 1;
    case TINYGLTF_COMPONENT_TYPE_SHORT:
    case TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT:
      return 2;
    case TINYGLTF_COMPONENT_TYPE_INT:
    case TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT:
    case TINYGLTF_COMPONENT_TYPE_FLOAT:
      return 4;
    case TINYGLTF_COMPONENT_TYPE_DOUBLE:
      return 8;
    default:
      return 0;
  }
}

double load_component(const unsigned char* p, int component_type) {
  // glTF binary data is little-endian.
  std::array<unsigned char, 8> b{};
  const std::size_t n = component_size(component_type);
  std::memcpy(b.data(), p, n);
  if constexpr (std::endian::native == std::endian::big)
    std::reverse(b.begin(), b.begin() + static_cast<long>(n));
  auto as = [&b](auto v) {
    std::memcpy(&v, b.data(), sizeof(v));
    return static_cast<double>(v);
  };
  switch (component_type) {
    case TINYGLTF_COMPONENT_TYPE_BYTE:
      return as(std::int8_t{});
    case TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE:
      return as(std::uint8_t{});
    case TINYGLTF_COMPONENT_TYPE_SHORT:
      return as(std::int16_t{});
    case TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT:
      return as(std::uint16_t{});
    case TINYGLTF_COMPONENT_TYPE_INT:
      return as(std::int32_t{});
    case TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT:
      return as(std::uint32_t{});
    case TINYGLTF_COMPONENT_TYPE_FLOAT:
      return as(float{});
    case TINYGLTF_COMPONENT_TYPE_DOUBLE:
      return as(double{});
    default:
      return 0.0;
  }
}

// Bounds-checked view of an accessor's elements: the model comes from untrusted bytes, so every
// offset, stride and count is checked against the real buffer size before reading.
struct AccessorView {
  const unsigned char* data = nullptr;
  std::size_t count = 0;
  std::size_t stride = 0;
  int component_type = 0;
  int components = 0;
  double get(std::size_t i, int c) const {
    return load_component(
        data + i * stride + static_cast<std::size_t>(c) * component_size(component_type),
        component_type);
  }
};

Result<AccessorView> view_accessor(const tinygltf::Model& model, int index,
                                   const std::string& what) {
  if (index < 0 || static_cast<std::size_t>(index) >= model.accessors.size()) {
    return invalid(what + ": accessor " + std::to_string(index) + " does not exist");
  }
  const tinygltf::Accessor& accessor = model.accessors[static_cast<std::size_t>(index)];
  const std::string name = what + " (accessor " + std::to_string(index) + ")";
  if (accessor.sparse.isSparse) return invalid(name + ": sparse accessors are not supported");
  if (accessor.bufferView < 0 ||
      static_cast<std::size_t>(accessor.bufferView) >= model.bufferViews.size()) {
    return invalid(name + ": missing or invalid bufferView " + std::to_string(accessor.bufferView));
  }
  const tinygltf::BufferView& view =
      model.bufferViews[static_cast<std::size_t>(accessor.bufferView)];
  if (view.buffer < 0 || static_cast<std::size_t>(view.buffer) >= model.buffers.size()) {
    return invalid(name + ": bufferView refers to missing buffer " + std::to_string(view.buffer));
  }
  const std::vector<unsigned char>& buffer =
      model.buffers[static_cast<std::size_t>(view.buffer)].data;
  AccessorView out;
  out.component_type = accessor.componentType;
  const std::size_t csize = component_size(accessor.componentType);
  if (csize == 0)
    return invalid(name + ": unknown componentType " + std::to_string(accessor.componentType));
  if (accessor.type == TINYGLTF_TYPE_SCALAR) {
    out.components = 1;
  } else if (accessor.type == TINYGLTF_TYPE_VEC3) {
    out.components = 3;
  } else {
    return invalid(name + ": unexpected accessor type " + std::to_string(accessor.type));
  }
  const std::size_t element = csize * static_cast<std::size_t>(out.components);
  out.stride = view.byteStride != 0 ? view.byteStride : element;
  out.count = accessor.count;
  if (out.stride < element) return invalid(name + ": byteStride smaller than an element");
  if (view.byteOffset > buffer.size() || view.byteLength > buffer.size() - view.byteOffset) {
    return invalid(name + ": bufferView exceeds its buffer (" + std::to_string(buffer.size()) +
                   " bytes)");
  }
  if (accessor.byteOffset > view.byteLength)
    return invalid(name + ": byteOffset exceeds its bufferView");
  const std::size_t available = view.byteLength - accessor.byteOffset;
  if (out.count > 0 && (out.count - 1 > available / out.stride ||
                        (out.count - 1) * out.stride + element > available)) {
    return invalid(name + ": " + std::to_string(out.count) + " elements exceed the bufferView (" +
                   std::to_string(view.byteLength) + " bytes)");
  }
  out.data = buffer.data() + view.byteOffset + accessor.byteOffset;
  return out;
}

// Nodes may share a mesh (instancing), so the output is not bounded by the input: a few kB of
// nodes referencing one large mesh would expand to gigabytes. Each primitive draws its vertices
// and corners from this budget, a fixed multiple of the input size.
struct GltfBudget {
  std::uint64_t elements_left = 0;
  Status take(std::uint64_t elements, const std::string& where) {
    if (elements > elements_left) {
      return invalid(where + ": instancing expands the mesh past " +
                     std::to_string(kExpansion) + " vertices and corners per input byte");
    }
    elements_left -= elements;
    return Status::success();
  }
  static constexpr std::uint64_t kExpansion = 2;
};

Status append_primitive(const tinygltf::Model& model, const tinygltf::Primitive& primitive,
                        const Eigen::Matrix4d& transform, bool is_identity,
                        const std::string& where, MeshBuilder& builder, WorkMeter& work,
                        GltfBudget& budget) {
  if (primitive.mode != TINYGLTF_MODE_TRIANGLES && primitive.mode != TINYGLTF_MODE_TRIANGLE_STRIP &&
      primitive.mode != TINYGLTF_MODE_TRIANGLE_FAN) {
    return Status::success();  // points and lines carry no surface
  }
  const auto position = primitive.attributes.find("POSITION");
  if (position == primitive.attributes.end()) return invalid(where + ": no POSITION attribute");
  MD_ASSIGN_OR_RETURN(const AccessorView positions,
                      view_accessor(model, position->second, where + " POSITION"));
  if (positions.components != 3 || (positions.component_type != TINYGLTF_COMPONENT_TYPE_FLOAT &&
                                    positions.component_type != TINYGLTF_COMPONENT_TYPE_DOUBLE)) {
    return invalid(where + ": POSITION must be VEC3 of float or double");
  }
  const std::size_t base = builder.vertex_count();
  if (base + positions.count > static_cast<std::size_t>(std::numeric_limits<int>::max())) {
    return invalid(where + ": too many vertices");
  }
  MD_RETURN_IF_ERROR(budget.take(positions.count, where));
  for (std::size_t i = 0; i < positions.count; ++i) {
    if ((i & 1023U) == 0) MD_RETURN_IF_ERROR(work.step(std::min<std::size_t>(1024, positions.count - i)));
    Eigen::Vector4d p(positions.get(i, 0), positions.get(i, 1), positions.get(i, 2), 1.0);
    if (!is_identity) p = transform * p;
    builder.add_vertex(p[0], p[1], p[2]);
  }
  std::vector<std::int64_t> corners;
  if (primitive.indices >= 0) {
    MD_ASSIGN_OR_RETURN(const AccessorView indices,
                        view_accessor(model, primitive.indices, where + " indices"));
    if (indices.components != 1 || indices.component_type == TINYGLTF_COMPONENT_TYPE_FLOAT ||
        indices.component_type == TINYGLTF_COMPONENT_TYPE_DOUBLE) {
      return invalid(where + ": indices must be integer scalars");
    }
    MD_RETURN_IF_ERROR(budget.take(indices.count, where));
    corners.reserve(indices.count);
    for (std::size_t i = 0; i < indices.count; ++i) {
      if ((i & 1023U) == 0) MD_RETURN_IF_ERROR(work.step(std::min<std::size_t>(1024, indices.count - i)));
      const double value = indices.get(i, 0);
      if (value < 0.0 || value >= static_cast<double>(positions.count)) {
        return invalid(where + ": index " + std::to_string(static_cast<std::int64_t>(value)) +
                       " at position " + std::to_string(i) + " is outside POSITION (count " +
                       std::to_string(positions.count) + ")");
      }
      corners.push_back(static_cast<std::int64_t>(value));
    }
  } else {
    MD_RETURN_IF_ERROR(budget.take(positions.count, where));
    corners.resize(positions.count);
    for (std::size_t i = 0; i < positions.count; ++i) corners[i] = static_cast<std::int64_t>(i);
  }
  const auto b = static_cast<int>(base);
  auto corner = [&](std::size_t i) { return b + static_cast<int>(corners[i]); };
  if (primitive.mode == TINYGLTF_MODE_TRIANGLES) {
    if (corners.size() % 3 != 0) {
      return invalid(where + ": TRIANGLES index count " + std::to_string(corners.size()) +
                     " is not a multiple of 3");
    }
    for (std::size_t i = 0; i < corners.size(); i += 3)
      builder.add_triangle(corner(i), corner(i + 1), corner(i + 2));
  } else if (primitive.mode == TINYGLTF_MODE_TRIANGLE_STRIP) {
    for (std::size_t i = 0; i + 2 < corners.size(); ++i) {
      if (i % 2 == 0) {
        builder.add_triangle(corner(i), corner(i + 1), corner(i + 2));
      } else {
        builder.add_triangle(corner(i + 1), corner(i), corner(i + 2));
      }
    }
  } else {
    for (std::size_t i = 1; i + 1 < corners.size(); ++i)
      builder.add_triangle(corner(0), corner(i), corner(i + 1));
  }
  return Status::success();
}

Eigen::Matrix4d node_transform(const tinygltf::Node& node) {
  Eigen::Matrix4d m = Eigen::Matrix4d::Identity();
  if (node.matrix.size() == 16) {
    for (int c = 0; c < 4; ++c) {
      for (int r = 0; r < 4; ++r)
        m(r, c) = node.matrix[static_cast<std::size_t>(4 * c + r)];  // column-major
    }
    return m;
  }
  Eigen::Affine3d t = Eigen::Affine3d::Identity();
  if (node.translation.size() == 3) {
    t.translate(Eigen::Vector3d(node.translation[0], node.translation[1], node.translation[2]));
  }
  if (node.rotation.size() == 4) {  // glTF order: x, y, z, w
    t.rotate(
        Eigen::Quaterniond(node.rotation[3], node.rotation[0], node.rotation[1], node.rotation[2])
            .normalized());
  }
  if (node.scale.size() == 3) t.scale(Eigen::Vector3d(node.scale[0], node.scale[1], node.scale[2]));
  return t.matrix();
}

Status append_mesh(const tinygltf::Model& model, int mesh_index, const Eigen::Matrix4d& transform,
                   MeshBuilder& builder, WorkMeter& work, GltfBudget& budget) {
  if (mesh_index < 0 || static_cast<std::size_t>(mesh_index) >= model.meshes.size()) {
    return invalid("glTF node refers to missing mesh " + std::to_string(mesh_index));
  }
  const bool is_identity = transform == Eigen::Matrix4d::Identity();
  const auto& primitives = model.meshes[static_cast<std::size_t>(mesh_index)].primitives;
  for (std::size_t p = 0; p < primitives.size(); ++p) {
    MD_RETURN_IF_ERROR(work.step());
    MD_RETURN_IF_ERROR(append_primitive(
        model, primitives[p], transform, is_identity,
        "glTF mesh " + std::to_string(mesh_index) + " primitive " + std::to_string(p), builder,
        work, budget));
  }
  return Status::success();
}

Result<MeshData> gltf_to_mesh(const tinygltf::Model& model, std::size_t input_bytes,
                              WorkMeter& work) {
  MeshBuilder builder;
  GltfBudget budget{GltfBudget::kExpansion * input_bytes};
  const int scene = model.defaultScene >= 0 ? model.defaultScene : (model.scenes.empty() ? -1 : 0);
  bool any_mesh_node = false;
  if (scene >= 0 && static_cast<std::size_t>(scene) < model.scenes.size()) {
    // Depth-first over the node hierarchy with world transforms. Cycles and exponential fan-out
    // are possible in hostile files: guard with an on-path flag and a visit budget.
    struct Item {
      int node;
      Eigen::Matrix4d parent;
    };
    std::vector<Item> stack;
    for (const int root : model.scenes[static_cast<std::size_t>(scene)].nodes) {
      stack.push_back({root, Eigen::Matrix4d::Identity()});
    }
    std::size_t visits = 0;
    const std::size_t visit_budget = 16 * (model.nodes.size() + 1);
    while (!stack.empty()) {
      const Item item = stack.back();
      stack.pop_back();
      if (item.node < 0 || static_cast<std::size_t>(item.node) >= model.nodes.size()) {
        return invalid("glTF scene refers to missing node " + std::to_string(item.node));
      }
      if (++visits > visit_budget) return invalid("glTF node hierarchy is cyclic or too deep");
      MD_RETURN_IF_ERROR(work.step());
      const tinygltf::Node& node = model.nodes[static_cast<std::size_t>(item.node)];
      const Eigen::Matrix4d world = item.parent * node_transform(node);
      if (node.mesh >= 0) {
        any_mesh_node = true;
        MD_RETURN_IF_ERROR(append_mesh(model, node.mesh, world, builder, work, budget));
      }
      for (auto it = node.children.rbegin(); it != node.children.rend(); ++it)
        stack.push_back({*it, world});
    }
  }
  if (!any_mesh_node) {
    // No scene graph: take every mesh as is.
    for (std::size_t m = 0; m < model.meshes.size(); ++m) {
      MD_RETURN_IF_ERROR(append_mesh(model, static_cast<int>(m), Eigen::Matrix4d::Identity(),
                                     builder, work, budget));
    }
  }
  return builder.finish("glTF");
}

// The JSON text of a .gltf, or the JSON chunk of a .glb (its binary chunk is not JSON); the
// whole input when the GLB header is malformed (tinygltf reports that).
std::string_view gltf_json_text(std::string_view bytes, bool is_binary) {
  if (!is_binary) return bytes;
  constexpr std::size_t kGlbHeader = 12, kChunkHeader = 8;
  if (bytes.size() < kGlbHeader + kChunkHeader) return {};
  const std::uint32_t length = load_u32_le(bytes.data() + kGlbHeader);
  return bytes.substr(kGlbHeader + kChunkHeader,
                      std::min<std::size_t>(length, bytes.size() - kGlbHeader - kChunkHeader));
}

}  // namespace

Result<MeshData> read_gltf(std::string_view bytes, bool allow_files, const std::string& base_dir,
                           WorkMeter& work) {
  if (bytes.size() > std::numeric_limits<unsigned int>::max())
    return invalid("glTF data is too large");
  {
    const bool glb = bytes.size() >= 4 && bytes.substr(0, 4) == "glTF";
    const std::string_view json_text = gltf_json_text(bytes, glb);
    MD_RETURN_IF_ERROR(work.step(json_text.size() / 16 + 1));
    if (json_nesting_depth(json_text, kMaxJsonDepth) > kMaxJsonDepth) {
      return invalid("glTF JSON nests arrays/objects deeper than " + std::to_string(kMaxJsonDepth) +
                     " levels");
    }
  }
  tinygltf::TinyGLTF loader;
  loader.SetImageLoader(&ignore_image, nullptr);
  if (!allow_files) {
    loader.SetFsCallbacks({&refuse_file_exists, &keep_path, &refuse_read, &refuse_write, nullptr});
  }
  tinygltf::Model model;
  std::string err;
  std::string warn;
  const bool is_binary = bytes.size() >= 4 && bytes.substr(0, 4) == "glTF";
  bool ok = false;
  if (is_binary) {
    ok = loader.LoadBinaryFromMemory(
        &model, &err, &warn, reinterpret_cast<const unsigned char*>(bytes.data()),
        static_cast<unsigned int>(bytes.size()), allow_files ? base_dir : "");
  } else {
    ok = loader.LoadASCIIFromString(&model, &err, &warn, bytes.data(),
                                    static_cast<unsigned int>(bytes.size()),
                                    allow_files ? base_dir : "");
  }
  if (!ok) {
    while (!err.empty() && is_space(err.back())) err.pop_back();
    return invalid("glTF reader: " + (err.empty() ? std::string("cannot parse data") : err));
  }
  MD_RETURN_IF_ERROR(work.poll());  // tinygltf's own parse cannot be stopped: check after it
  return gltf_to_mesh(model, bytes.size(), work);
}

Result<std::string> write_gltf(const MeshData& mesh, bool binary) {
  const auto nv = static_cast<std::size_t>(mesh.V.rows());
  const auto nf = static_cast<std::size_t>(mesh.F.rows());
  tinygltf::Model model;
  model.asset.version = "2.0";
  model.asset.generator = "meshdeform";
  tinygltf::Buffer buffer;
  std::string bytes;
  bytes.reserve(12 * nv + 12 * nf);
  std::vector<double> lo(3, std::numeric_limits<double>::infinity());
  std::vector<double> hi(3, -std::numeric_limits<double>::infinity());
  for (std::size_t i = 0; i < nv; ++i) {
    for (int c = 0; c < 3; ++c) {
      const float v = static_cast<float>(mesh.V(static_cast<Eigen::Index>(i), c));
      append_f32_le(bytes, v);
      lo[static_cast<std::size_t>(c)] =
          std::min(lo[static_cast<std::size_t>(c)], static_cast<double>(v));
      hi[static_cast<std::size_t>(c)] =
          std::max(hi[static_cast<std::size_t>(c)], static_cast<double>(v));
    }
  }
  for (std::size_t f = 0; f < nf; ++f) {
    for (int c = 0; c < 3; ++c)
      append_u32_le(bytes, static_cast<std::uint32_t>(mesh.F(static_cast<Eigen::Index>(f), c)));
  }
  buffer.data.assign(bytes.begin(), bytes.end());
  model.buffers.push_back(std::move(buffer));

  tinygltf::BufferView positions_view;
  positions_view.buffer = 0;
  positions_view.byteOffset = 0;
  positions_view.byteLength = 12 * nv;
  positions_view.target = TINYGLTF_TARGET_ARRAY_BUFFER;
  tinygltf::BufferView indices_view;
  indices_view.buffer = 0;
  indices_view.byteOffset = 12 * nv;
  indices_view.byteLength = 12 * nf;
  indices_view.target = TINYGLTF_TARGET_ELEMENT_ARRAY_BUFFER;
  model.bufferViews = {positions_view, indices_view};

  tinygltf::Accessor positions;
  positions.bufferView = 0;
  positions.componentType = TINYGLTF_COMPONENT_TYPE_FLOAT;
  positions.type = TINYGLTF_TYPE_VEC3;
  positions.count = nv;
  positions.minValues = lo;  // required for POSITION by the glTF spec
  positions.maxValues = hi;
  tinygltf::Accessor indices;
  indices.bufferView = 1;
  indices.componentType = TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT;
  indices.type = TINYGLTF_TYPE_SCALAR;
  indices.count = 3 * nf;
  model.accessors = {positions, indices};

  tinygltf::Primitive primitive;
  primitive.attributes["POSITION"] = 0;
  primitive.indices = 1;
  primitive.mode = TINYGLTF_MODE_TRIANGLES;
  tinygltf::Mesh gltf_mesh;
  gltf_mesh.primitives.push_back(primitive);
  model.meshes.push_back(gltf_mesh);
  tinygltf::Node node;
  node.mesh = 0;
  model.nodes.push_back(node);
  tinygltf::Scene scene;
  scene.nodes.push_back(0);
  model.scenes.push_back(scene);
  model.defaultScene = 0;

  tinygltf::TinyGLTF writer;
  writer.SetFsCallbacks({&refuse_file_exists, &keep_path, &refuse_read, &refuse_write, nullptr});
  std::ostringstream stream;
  if (!writer.WriteGltfSceneToStream(&model, stream, /*prettyPrint=*/!binary, binary)) {
    return Error(ErrorCode::Internal, "glTF writer failed");
  }
  return stream.str();
}

// Every public entry point funnels through here so that no exception (bad_alloc from a huge
// allocation, anything thrown inside tinygltf/nlohmann) escapes the API.

}  // namespace meshdeform::io::detail
