#pragma once
/// @file failed_start.h
/// For the Redis suites' startup-error tests: runs meshdeform-server (MESHDEFORM_SERVER_PATH,
/// defined for this test target) with `flags` expecting it to stop at startup.

#include <chrono>
#include <filesystem>
#include <fstream>
#include <optional>
#include <random>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

#include <gtest/gtest.h>

#include "tests/support/child_process.h"

namespace meshdeform::test {

/// @param env  extra environment entries ("NAME=value"); MESHDEFORM_REDIS_PASSWORD is unset.
/// @return the exit status (nullopt if it did not stop within 60 s) and its stderr.
inline std::pair<std::optional<int>, std::string> failed_start(
    const std::vector<std::string>& flags, const std::vector<std::string>& env = {}) {
  namespace fs = std::filesystem;
  std::random_device random;
  const std::string log =
      (fs::temp_directory_path() / ("meshdeform-redis-start-" + std::to_string(random()))).string();
  std::vector<std::string> args = {MESHDEFORM_SERVER_PATH, "--listen", "127.0.0.1:0"};
  args.insert(args.end(), flags.begin(), flags.end());
  ChildStreams streams;
  streams.stderr_path = log;
  streams.env = env;
  streams.unset_env = {"MESHDEFORM_REDIS_PASSWORD"};
  std::string error;
  std::optional<ChildProcess> child = ChildProcess::spawn(args, streams, error);
  EXPECT_TRUE(child.has_value()) << error;
  if (!child) return {std::nullopt, error};
  std::optional<int> status = child->wait(std::chrono::milliseconds(60'000));
  std::ifstream in(log);
  std::stringstream text;
  text << in.rdbuf();
  std::error_code ignored;
  fs::remove(log, ignored);
  return {status, text.str()};
}

}  // namespace meshdeform::test
