// Every relative link of the project's Markdown (README.md, CHANGELOG.md, docs/*.md and the
// sub-READMEs) points at a file of the repository, and every #anchor at a heading of its target
// (GitHub's slugs: lower case, punctuation dropped, spaces to hyphens, repeats numbered).
// Links inside fenced code blocks and absolute URLs are not checked.
#include <gtest/gtest.h>

#include <cctype>
#include <filesystem>
#include <fstream>
#include <map>
#include <regex>
#include <set>
#include <sstream>
#include <string>
#include <vector>

namespace {

namespace fs = std::filesystem;
const fs::path kRoot = MESHDEFORM_SOURCE_DIR;

std::string read_file(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream text;
  text << in.rdbuf();
  return text.str();
}

/// The lines of `text` outside fenced code blocks.
std::vector<std::string> prose_lines(const std::string& text) {
  std::vector<std::string> lines;
  std::istringstream in(text);
  std::string line;
  bool fenced = false;
  while (std::getline(in, line)) {
    const std::size_t first = line.find_first_not_of(' ');
    if (first != std::string::npos && line.compare(first, 3, "```") == 0) {
      fenced = !fenced;
      continue;
    }
    if (!fenced) lines.push_back(line);
  }
  return lines;
}

/// GitHub's anchor of a heading's text.
std::string slug(const std::string& heading) {
  // Link text stays, the target goes: "[a](b)" -> "a".
  const std::string text = std::regex_replace(heading, std::regex(R"(\[([^\]]*)\]\([^)]*\))"), "$1");
  std::string out;
  for (const unsigned char c : text) {
    if (std::isalnum(c) || c == '-' || c == '_' || c >= 0x80) {
      out.push_back(static_cast<char>(std::tolower(c)));
    } else if (c == ' ') {
      out.push_back('-');
    }
  }
  return out;
}

/// The anchors of a Markdown file's headings.
std::set<std::string> anchors_of(const fs::path& path) {
  std::set<std::string> anchors;
  std::map<std::string, int> seen;
  for (const std::string& line : prose_lines(read_file(path))) {
    std::smatch match;
    if (!std::regex_match(line, match, std::regex(R"(#{1,6}\s+(.*?)\s*#*\s*)"))) continue;
    std::string anchor = slug(match[1].str());
    const int count = seen[anchor]++;
    if (count > 0) anchor.append(1, '-').append(std::to_string(count));
    anchors.insert(anchor);
  }
  return anchors;
}

std::vector<fs::path> markdown_files() {
  std::vector<fs::path> files;
  for (const char* name : {"README.md", "CHANGELOG.md", "bench/README.md", "docker/README.md",
                           "web_viewer/README.md"}) {
    if (fs::exists(kRoot / name)) files.push_back(kRoot / name);
  }
  if (fs::is_directory(kRoot / "docs")) {
    for (const auto& entry : fs::directory_iterator(kRoot / "docs")) {
      if (entry.path().extension() == ".md") files.push_back(entry.path());
    }
  }
  return files;
}

TEST(DocLinksTest, EveryRelativeLinkAndAnchorResolves) {
  const std::vector<fs::path> files = markdown_files();
  ASSERT_FALSE(files.empty());
  const std::regex link(R"(!?\[(?:[^\]\[]|\[[^\]]*\])*\]\(([^)\s]+)(?:\s+"[^"]*")?\))");
  int checked = 0;
  std::map<fs::path, std::set<std::string>> anchors;  // per target, computed once
  for (const fs::path& file : files) {
    for (const std::string& line : prose_lines(read_file(file))) {
      // Inline code is not a link.
      const std::string prose = std::regex_replace(line, std::regex("`[^`]*`"), "");
      for (auto it = std::sregex_iterator(prose.begin(), prose.end(), link);
           it != std::sregex_iterator(); ++it) {
        const std::string target = (*it)[1].str();
        if (target.rfind("http://", 0) == 0 || target.rfind("https://", 0) == 0 ||
            target.rfind("mailto:", 0) == 0) {
          continue;
        }
        ++checked;
        const std::size_t hash = target.find('#');
        const std::string path_part = target.substr(0, hash);
        const fs::path resolved =
            path_part.empty() ? file : (file.parent_path() / path_part).lexically_normal();
        EXPECT_TRUE(fs::exists(resolved))
            << fs::relative(file, kRoot).string() << ": link to a missing file: " << target;
        if (hash != std::string::npos && fs::exists(resolved) && resolved.extension() == ".md") {
          const std::string anchor = target.substr(hash + 1);
          if (!anchors.count(resolved)) anchors[resolved] = anchors_of(resolved);
          EXPECT_TRUE(anchors[resolved].count(anchor) == 1)
              << fs::relative(file, kRoot).string() << ": no heading for the anchor #" << anchor
              << " in " << fs::relative(resolved, kRoot).string();
        }
      }
    }
  }
  EXPECT_GT(checked, 0);
}

TEST(DocLinksTest, SlugsFollowGitHub) {
  EXPECT_EQ(slug("Reliability: what each store promises"), "reliability-what-each-store-promises");
  EXPECT_EQ(slug("Sessions on Redis (issue 16)"), "sessions-on-redis-issue-16");
  EXPECT_EQ(slug("Large meshes: multiresolution (issue 15, core part)"),
            "large-meshes-multiresolution-issue-15-core-part");
  EXPECT_EQ(slug("The `--state-dir` store"), "the---state-dir-store");
}

}  // namespace
