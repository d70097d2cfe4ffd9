#include "bench/machine_info.h"

#include <sched.h>
#include <unistd.h>

#include <array>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <memory>
#include <string>
#include <system_error>

#include "bench/bench_config.h"

namespace meshdeform::bench {
namespace {

std::string trim(std::string s) {
  const auto first = s.find_first_not_of(" \t\r\n");
  if (first == std::string::npos) return {};
  const auto last = s.find_last_not_of(" \t\r\n");
  return s.substr(first, last - first + 1);
}

std::string cpu_model() {
  std::ifstream in("/proc/cpuinfo");
  std::string line;
  while (std::getline(in, line)) {
    if (line.rfind("model name", 0) == 0) {
      const auto colon = line.find(':');
      if (colon != std::string::npos) return trim(line.substr(colon + 1));
    }
  }
  return "unknown";
}

std::string blas_library() {
  // Debian selects libblas.so.3 through update-alternatives; CHOLMOD's supernodal factorization
  // runs on whatever it points to (reference BLAS, OpenBLAS pthread/openmp, BLIS, MKL).
  for (const char* link : {"/etc/alternatives/libblas.so.3-x86_64-linux-gnu",
                           "/usr/lib/x86_64-linux-gnu/libblas.so.3"}) {
    std::error_code error;
    const auto target = std::filesystem::canonical(link, error);
    if (!error) return target.string();
  }
  return "unknown";
}

std::string env_or_unset(const char* name) {
  const char* value = std::getenv(name);
  return std::string(name) + "=" + (value != nullptr ? value : "unset");
}

std::string git_revision() {
  const std::string command =
      "git -C '" MESHDEFORM_BENCH_SOURCE_DIR "' describe --always --dirty 2>/dev/null";
  std::unique_ptr<FILE, int (*)(FILE*)> pipe(popen(command.c_str(), "r"), pclose);
  if (!pipe) return "unknown";
  std::array<char, 128> buffer{};
  std::string out;
  while (std::fgets(buffer.data(), static_cast<int>(buffer.size()), pipe.get()) != nullptr) {
    out += buffer.data();
  }
  out = trim(out);
  return out.empty() ? "unknown" : out;
}

std::string date_utc() {
  const std::time_t now = std::chrono::system_clock::to_time_t(std::chrono::system_clock::now());
  std::tm tm{};
  gmtime_r(&now, &tm);
  std::array<char, 32> buffer{};
  std::strftime(buffer.data(), buffer.size(), "%Y-%m-%dT%H:%M:%SZ", &tm);
  return buffer.data();
}

}  // namespace

std::string read_load_average() {
  // Other jobs on a shared machine skew every timing: record how busy it was.
  std::ifstream in("/proc/loadavg");
  std::string one, five, fifteen;
  if (!(in >> one >> five >> fifteen)) return "unknown";
  return one + " " + five + " " + fifteen;
}

MachineInfo collect_machine_info() {
  MachineInfo info;
  info.date_utc = date_utc();
  // `nproc` counts the CPUs this process may run on (its affinity mask), not all online ones.
  cpu_set_t cpus;
  CPU_ZERO(&cpus);
  info.hardware_threads = sched_getaffinity(0, sizeof(cpus), &cpus) == 0
                              ? CPU_COUNT(&cpus)
                              : static_cast<int>(sysconf(_SC_NPROCESSORS_ONLN));
  info.cpu_model = cpu_model();
  info.blas = blas_library();
  info.blas_env = env_or_unset("OPENBLAS_NUM_THREADS") + ", " + env_or_unset("OMP_NUM_THREADS");
  info.compiler = MESHDEFORM_BENCH_COMPILER;
  info.build_type = MESHDEFORM_BENCH_BUILD_TYPE;
  info.git_revision = git_revision();
  info.load_average = read_load_average();
  return info;
}

nlohmann::json machine_json(const MachineInfo& machine, const std::string& load_end) {
  return {{"date_utc", machine.date_utc},
          {"nproc", machine.hardware_threads},
          {"cpu_model", machine.cpu_model},
          {"blas", machine.blas},
          {"blas_env", machine.blas_env},
          {"compiler", machine.compiler},
          {"build_type", machine.build_type},
          {"git_revision", machine.git_revision},
          {"load_average_start", machine.load_average},
          {"load_average_end", load_end}};
}

}  // namespace meshdeform::bench
