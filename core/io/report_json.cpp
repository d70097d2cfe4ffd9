#include "core/io/report_json.h"

namespace meshdeform::io {

nlohmann::json iteration_to_json(const core::IterationInfo& info) {
  return {{"iteration", info.iteration},
          {"energy", info.energy},
          {"energy_before", info.energy_before},
          {"e_theta", info.e_theta},
          {"e_phi", info.e_phi},
          {"elapsed_seconds", info.elapsed_seconds},
          {"pcg_iterations", info.pcg_iterations},
          {"normal_sweeps", info.normal_sweeps},
          {"refactored", info.refactored},
          {"normals_seconds", info.normals_seconds},
          {"assemble_seconds", info.assemble_seconds},
          {"linear_seconds", info.linear_seconds}};
}

nlohmann::json history_to_json(const std::vector<core::IterationInfo>& history) {
  nlohmann::json out = nlohmann::json::array();
  for (const core::IterationInfo& info : history) out.push_back(iteration_to_json(info));
  return out;
}

}  // namespace meshdeform::io
