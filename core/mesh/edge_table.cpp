#include "core/mesh/edge_table.h"

#include <algorithm>
#include <utility>

namespace meshdeform::core {
namespace {

// Corners per vertex up to which an insertion sort orders them (the usual case: 3-8).
constexpr int kInsertionSortMax = 32;

}  // namespace

EdgeTable build_edge_table(const Triangles& F, int vertex_count) {
  const int nf = static_cast<int>(F.rows());
  const int corner_count = 3 * nf;
  auto ends = [&F](int c, int& a, int& b) {
    a = F(c / 3, c % 3);
    b = F(c / 3, (c % 3 + 1) % 3);
  };
  // Counting sort of the corners by their smaller vertex; ascending corner order within each.
  std::vector<int> start(static_cast<std::size_t>(vertex_count) + 1, 0);
  for (int c = 0; c < corner_count; ++c) {
    int a = 0, b = 0;
    ends(c, a, b);
    ++start[static_cast<std::size_t>(std::min(a, b)) + 1];
  }
  for (int v = 0; v < vertex_count; ++v) start[v + 1] += start[v];
  std::vector<int> by_lo(static_cast<std::size_t>(corner_count));
  std::vector<int> next(start.begin(), start.end() - 1);
  for (int c = 0; c < corner_count; ++c) {
    int a = 0, b = 0;
    ends(c, a, b);
    by_lo[static_cast<std::size_t>(next[static_cast<std::size_t>(std::min(a, b))]++)] = c;
  }
  // Each vertex's few corners by (larger vertex, corner): a stable insertion sort on the larger.
  std::vector<int> other(static_cast<std::size_t>(corner_count));
  for (int i = 0; i < corner_count; ++i) {
    int a = 0, b = 0;
    ends(by_lo[static_cast<std::size_t>(i)], a, b);
    other[static_cast<std::size_t>(i)] = std::max(a, b);
  }
  EdgeTable t;
  t.corners.resize(static_cast<std::size_t>(corner_count));
  t.edge_of.resize(static_cast<std::size_t>(corner_count));
  t.offsets.reserve(static_cast<std::size_t>(corner_count) / 2 + 2);
  t.lo.reserve(static_cast<std::size_t>(corner_count) / 2 + 1);
  t.hi.reserve(static_cast<std::size_t>(corner_count) / 2 + 1);
  for (int v = 0; v < vertex_count; ++v) {
    const int first = start[static_cast<std::size_t>(v)];
    const int end = start[static_cast<std::size_t>(v) + 1];
    if (end - first > kInsertionSortMax) {
      // A high-degree vertex (e.g. the centre of a fan): O(d log d), not an insertion sort's d^2.
      std::vector<std::pair<int, int>> rows(static_cast<std::size_t>(end - first));
      for (int i = first; i < end; ++i) {
        rows[static_cast<std::size_t>(i - first)] = {other[static_cast<std::size_t>(i)],
                                                     by_lo[static_cast<std::size_t>(i)]};
      }
      std::sort(rows.begin(), rows.end());
      for (int i = first; i < end; ++i) {
        other[static_cast<std::size_t>(i)] = rows[static_cast<std::size_t>(i - first)].first;
        by_lo[static_cast<std::size_t>(i)] = rows[static_cast<std::size_t>(i - first)].second;
      }
    } else {
      for (int i = first + 1; i < end; ++i) {
        const int key = other[static_cast<std::size_t>(i)];
        const int corner = by_lo[static_cast<std::size_t>(i)];
        int j = i - 1;
        for (; j >= first && other[static_cast<std::size_t>(j)] > key; --j) {
          other[static_cast<std::size_t>(j) + 1] = other[static_cast<std::size_t>(j)];
          by_lo[static_cast<std::size_t>(j) + 1] = by_lo[static_cast<std::size_t>(j)];
        }
        other[static_cast<std::size_t>(j) + 1] = key;
        by_lo[static_cast<std::size_t>(j) + 1] = corner;
      }
    }
    for (int i = first; i < end; ++i) {
      const int hi = other[static_cast<std::size_t>(i)];
      if (i == first || hi != other[static_cast<std::size_t>(i) - 1]) {
        t.offsets.push_back(i);
        t.lo.push_back(v);
        t.hi.push_back(hi);
      }
      const int corner = by_lo[static_cast<std::size_t>(i)];
      t.corners[static_cast<std::size_t>(i)] = corner;
      t.edge_of[static_cast<std::size_t>(corner)] = static_cast<int>(t.lo.size()) - 1;
    }
  }
  t.offsets.push_back(corner_count);
  return t;
}

}  // namespace meshdeform::core
