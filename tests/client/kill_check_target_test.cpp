// The target of scripts/kill-check.sh (disabled: it is not a test by itself). It starts a real
// meshdeform-server, says so on stdout, then waits idle (bounded) to be killed with SIGKILL; the
// script then checks that the idle server died with it and that nothing holds the test's stdout.
// An idle server is the hard case: one with calls in flight dies anyway of SIGPIPE on its next
// log line, an idle one lived on and kept ctest waiting on the pipe.

#include <gtest/gtest.h>

#include <chrono>
#include <iostream>
#include <thread>

#include "tests/support/server_process.h"

namespace meshdeform {
namespace {

TEST(KillCheckTarget, DISABLED_HoldsAnIdleServerUntilKilled) {
  std::string error;
  auto server = test::ServerProcess::start(MESHDEFORM_SERVER_PATH, {}, error);
  ASSERT_NE(server, nullptr) << error;
  std::cout << "kill-check-target: server " << server->pid() << " ready" << std::endl;
  std::this_thread::sleep_for(std::chrono::seconds(120));  // bounded: the script kills us first
}

}  // namespace
}  // namespace meshdeform
