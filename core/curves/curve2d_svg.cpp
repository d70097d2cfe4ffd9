#include "core/curves/curve2d_svg.h"

#include <algorithm>
#include <cstdio>
#include <string>
#include <utility>
#include <vector>

#include "core/base/format_number.h"

namespace meshdeform::core {
namespace {

std::string xml_escape(const std::string& text) {
  std::string out;
  for (const char ch : text) {
    switch (ch) {
      case '&':
        out += "&amp;";
        break;
      case '<':
        out += "&lt;";
        break;
      case '>':
        out += "&gt;";
        break;
      case '"':
        out += "&quot;";
        break;
      default:
        out += ch;
    }
  }
  return out;
}

}  // namespace

std::string curve_comparison_svg(const CurveEdit& edit, const std::vector<CurvePanel>& panels) {
  // One scale for every panel, so the results compare at a glance.
  Eigen::RowVector2d lo = edit.rest.P.colwise().minCoeff(), hi = edit.rest.P.colwise().maxCoeff();
  auto include = [&](const Points2& P) {
    if (P.rows() == 0) return;
    lo = lo.cwiseMin(P.colwise().minCoeff());
    hi = hi.cwiseMax(P.colwise().maxCoeff());
  };
  include(edit.targets);
  for (const CurvePanel& panel : panels) include(panel.P);
  const Eigen::RowVector2d extent = (hi - lo).cwiseMax(1e-9);
  constexpr double kPlotWidth = 300, kMargin = 20, kTitle = 28, kCaption = 30;
  const double scale = kPlotWidth / std::max(extent.x(), extent.y() * 0.5);
  const double plot_w = extent.x() * scale, plot_h = extent.y() * scale;
  const double panel_w = plot_w + 2 * kMargin;
  const double panel_h = kTitle + plot_h + 2 * kMargin + kCaption;
  const size_t panel_count = panels.size() + 1;
  const double total_w = panel_w * static_cast<double>(panel_count);

  auto xy = [&](size_t panel, double x, double y) {
    const double px = panel_w * static_cast<double>(panel) + kMargin + (x - lo.x()) * scale;
    const double py = kTitle + kMargin + (hi.y() - y) * scale;
    return std::make_pair(px, py);
  };
  auto polyline = [&](size_t panel, const Points2& P, const char* colour) {
    std::string s = "  <polyline fill=\"none\" stroke=\"" + std::string(colour) +
                    "\" stroke-width=\"1.2\" stroke-linejoin=\"round\" points=\"";
    for (Eigen::Index i = 0; i < P.rows(); ++i) {
      const auto [px, py] = xy(panel, P(i, 0), P(i, 1));
      s += format_number(px, "%.2f") + "," + format_number(py, "%.2f") + " ";
    }
    if (edit.rest.closed && P.rows() > 0) {
      const auto [px, py] = xy(panel, P(0, 0), P(0, 1));
      s += format_number(px, "%.2f") + "," + format_number(py, "%.2f");
    }
    return s + "\"/>\n";
  };
  auto circle = [&](size_t panel, double x, double y, const char* fill, const char* stroke) {
    const auto [px, py] = xy(panel, x, y);
    return "  <circle cx=\"" + format_number(px, "%.2f") + "\" cy=\"" + format_number(py, "%.2f") +
           "\" r=\"4\" fill=\"" + fill + "\" stroke=\"" + stroke + "\" stroke-width=\"1.5\"/>\n";
  };
  auto text = [&](size_t panel, double y, const std::string& content, int size) {
    const double cx = panel_w * (static_cast<double>(panel) + 0.5);
    return "  <text x=\"" + format_number(cx, "%.1f") + "\" y=\"" + format_number(y, "%.1f") +
           "\" text-anchor=\"middle\" font-family=\"sans-serif\" font-size=\"" +
           std::to_string(size) + "\">" + content + "</text>\n";
  };
  auto constraint_marks = [&](size_t panel, bool at_rest) {
    std::string s;
    for (Eigen::Index j = 0; j < edit.constrained.size(); ++j) {
      const bool is_handle = edit.constrained(j) == edit.handle;
      const Eigen::RowVector2d p =
          at_rest ? Eigen::RowVector2d(edit.rest.P.row(edit.constrained(j))) : edit.targets.row(j);
      s += circle(panel, p.x(), p.y(), is_handle ? "#d62728" : "#2ca02c", "black");
    }
    return s;
  };

  std::string svg;
  svg += "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n";
  svg += "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"" + format_number(total_w, "%.0f") +
         "\" height=\"" + format_number(panel_h, "%.0f") + "\" viewBox=\"0 0 " +
         format_number(total_w, "%.2f") + " " + format_number(panel_h, "%.2f") + "\">\n";
  svg += "  <title>2D curve editing (Liu et al., Fig. 9): original, then each method</title>\n";
  svg += "  <rect width=\"100%\" height=\"100%\" fill=\"white\"/>\n";
  const double caption_y = panel_h - kCaption / 2 + 4;

  // Panel 0: the original, fixed points green, the handle red with a dashed arrow to its target.
  svg += text(0, kTitle - 8, "(a) original", 15);
  svg += polyline(0, edit.rest.P, "#1f3b73");
  for (Eigen::Index j = 0; j < edit.constrained.size(); ++j) {
    if (edit.constrained(j) != edit.handle) continue;
    const auto [x0, y0] = xy(0, edit.rest.P(edit.handle, 0), edit.rest.P(edit.handle, 1));
    const auto [x1, y1] = xy(0, edit.targets(j, 0), edit.targets(j, 1));
    svg += "  <line x1=\"" + format_number(x0, "%.2f") + "\" y1=\"" + format_number(y0, "%.2f") + "\" x2=\"" +
           format_number(x1, "%.2f") + "\" y2=\"" + format_number(y1, "%.2f") +
           "\" stroke=\"#d62728\" stroke-width=\"1.5\" stroke-dasharray=\"4 3\"/>\n";
    svg += circle(0, edit.targets(j, 0), edit.targets(j, 1), "none", "#d62728");
  }
  svg += constraint_marks(0, true);
  svg += text(0, caption_y, std::to_string(edit.rest.P.rows()) + " points", 13);

  for (size_t k = 0; k < panels.size(); ++k) {
    const size_t panel = k + 1;
    // Built by appends: "(" + std::string(1, c) + ") " trips a false -Wrestrict in GCC 12.
    std::string label = "(";
    label += static_cast<char>('b' + k % 25);
    label += ") ";
    svg += "  <line x1=\"" + format_number(panel_w * static_cast<double>(panel), "%.1f") +
           "\" y1=\"0\" x2=\"" + format_number(panel_w * static_cast<double>(panel), "%.1f") +
           "\" y2=\"" + format_number(panel_h, "%.1f") + "\" stroke=\"#cccccc\"/>\n";
    svg += text(panel, kTitle - 8, label + xml_escape(panels[k].title), 15);
    svg += polyline(panel, panels[k].P, "#1f3b73");
    svg += constraint_marks(panel, false);
    svg += text(panel, caption_y,
                "E<tspan font-style=\"italic\">&#952;</tspan> = " +
                    format_number(panels[k].e_theta, "%.4f") + " rad",
                13);
  }
  svg += "</svg>\n";
  return svg;
}

}  // namespace meshdeform::core
