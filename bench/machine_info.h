#pragma once
/// @file machine_info.h
/// Where a benchmark ran: the facts a reader needs to compare two result files.

#include <string>

#include <nlohmann/json.hpp>

namespace meshdeform::bench {

/// Machine, library and build facts, each a printable string ("unknown" when not found).
struct MachineInfo {
  std::string date_utc;       ///< "2024-05-01T12:00:00Z"
  int hardware_threads = 0;   ///< what `nproc` prints (online CPUs)
  std::string cpu_model;      ///< "model name" of /proc/cpuinfo
  std::string blas;           ///< realpath of the libblas.so.3 alternative
  std::string blas_env;       ///< OPENBLAS_NUM_THREADS / OMP_NUM_THREADS as set, or "unset"
  std::string compiler;       ///< compiler id and version
  std::string build_type;     ///< CMAKE_BUILD_TYPE and its flags
  std::string git_revision;   ///< `git describe --always --dirty` of the source tree
  std::string load_average;   ///< 1/5/15-minute load of /proc/loadavg when collected
};

/// "1.02 0.87 0.40": the 1/5/15-minute load of /proc/loadavg, or "unknown".
std::string read_load_average();

/// Collects the facts (reads /proc, /etc/alternatives and the environment; runs git once).
MachineInfo collect_machine_info();

/// The "machine" object of a results file: every fact, the load at start and `load_end`.
nlohmann::json machine_json(const MachineInfo& machine, const std::string& load_end);

}  // namespace meshdeform::bench
