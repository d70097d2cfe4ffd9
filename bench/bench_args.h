#pragma once
// What every benchmark executable shares: comma lists, bounded integers, writing a results
// file, and a main() that prints usage for --help (and after a bad flag) and turns errors into exit code 1.

#include <exception>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <sstream>
#include <string>
#include <vector>

#include "core/status.h"

namespace meshdeform::bench {

/// "a,b,,c" -> {"a", "b", "c"}.
inline std::vector<std::string> split_commas(const std::string& text) {
  std::vector<std::string> out;
  std::stringstream in(text);
  std::string item;
  while (std::getline(in, item, ',')) {
    if (!item.empty()) out.push_back(item);
  }
  return out;
}

/// All of `text` as an integer >= min_value; InvalidArgument naming `flag` otherwise.
template <typename Integer>
Result<Integer> parse_integer(const std::string& flag, const std::string& text, Integer min_value) {
  try {
    std::size_t used = 0;
    const long long value = std::stoll(text, &used);
    if (used == text.size() && value >= static_cast<long long>(min_value)) {
      return static_cast<Integer>(value);
    }
  } catch (const std::exception&) {
  }
  return Error(ErrorCode::InvalidArgument,
               flag + " wants an integer >= " + std::to_string(min_value) + ", got '" + text + "'");
}

/// Writes a results file. @return Internal naming the path if it cannot be written.
inline Status write_file(const std::filesystem::path& path, const std::string& text) {
  std::ofstream out(path);
  out << text;
  if (!out) return Error(ErrorCode::Internal, "cannot write " + path.string());
  return Status::success();
}

/// main() of a benchmark: --help/-h prints `usage` and exits 0; `run` returning an error prints
/// it (and the usage, for a bad flag) and exits 1, as does an escaped exception.
template <typename Usage, typename Run>
int bench_main(int argc, char** argv, const char* name, Usage&& usage, Run&& run) {
  for (int i = 1; i < argc; ++i) {
    if (std::string(argv[i]) == "--help" || std::string(argv[i]) == "-h") {
      usage(std::cout);
      return 0;
    }
  }
  try {
    const Status status = run(argc, argv);
    if (!status.ok()) {
      std::cerr << name << ": " << status.to_string() << "\n";
      if (status.code() == ErrorCode::InvalidArgument) usage(std::cerr);
      return 1;
    }
  } catch (const std::exception& e) {
    std::cerr << name << ": " << e.what() << "\n";
    return 1;
  }
  return 0;
}

}  // namespace meshdeform::bench
